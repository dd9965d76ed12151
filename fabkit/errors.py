"""The one exception type for problems a user can cause and fix."""


class FabkitError(Exception):
    """A problem with user input (spec, file, profile, port, ...).

    The message is one line that names the problem and, where possible, the fix.
    The command line prints it as ``fabkit: error: <message>`` and exits with code 2.
    """
