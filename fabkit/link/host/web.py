"""Talking to a printer host over HTTP: its URL, its API key, one client with timeouts and
retries, and what every host can do (:class:`PrintHost`).

``octoprint+http://host:port`` and ``moonraker+http://host:port`` (or ``+https``) name the
host and its kind; plain ``http://`` and ``https://`` leave the kind to the server
(:func:`fabkit.link.host.hosts.ask_kind` asks it). A path after the port is kept (a host
behind a reverse proxy at ``/octoprint``). The API key is never part of a message, a log
line or a report; it travels only in the ``X-Api-Key`` header, which both hosts read.
"""

from __future__ import annotations

import os
import re
import time
import urllib.parse
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TextIO

from fabkit.errors import FabkitError
from fabkit.machines import MachineProfile

if TYPE_CHECKING:
    import requests

KEY_ENV = "FABKIT_API_KEY"
"""The environment variable an API key may come from (after --api-key and --api-key-file)."""
KEY_SOURCES = f"--api-key, --api-key-file or {KEY_ENV}"
_SCHEMES = {
    "octoprint+http": "octoprint",
    "octoprint+https": "octoprint",
    "moonraker+http": "moonraker",
    "moonraker+https": "moonraker",
    "http": None,
    "https": None,
}
_KEY = re.compile(r"[\x21-\x7e]+")  # what an HTTP header value can carry as it is
_ERRNO = re.compile(r"\[Errno -?\d+\] ([^'\")]+)")


@dataclass(frozen=True)
class HostURL:
    """A printer host as the user named it: ``kind`` (``octoprint``, ``moonraker``, or
    None for plain http(s)://, to be asked), the ``base`` URL the API paths are appended
    to, and ``text``, the URL as given, which names the host in every message."""

    kind: str | None
    base: str
    text: str


@dataclass(frozen=True)
class HostOptions:
    """Timing of a printer host's link (s).

    Progress is queried every ``poll_s``. A connection must open within ``connect_s``, an
    answer come within ``answer_s`` (``upload_s`` for an upload's). A connection that
    fails is tried ``retries`` more times (nothing was sent); a GET, idempotent, also after
    a gateway error (502, 503, 504) or, once, a timeout. Progress queries may fail for
    ``lost_s`` before the link counts as lost; a started job must show within
    ``start_s``, a cancelled one stop within ``cancel_s``.
    """

    poll_s: float = 0.5
    connect_s: float = 5.0
    answer_s: float = 30.0
    upload_s: float = 600.0
    retries: int = 3
    lost_s: float = 30.0
    start_s: float = 10.0
    cancel_s: float = 30.0


@dataclass(frozen=True)
class JobState:
    """A host's job as one progress query saw it: the server's own word for its state,
    whether a job runs or is paused (``active``) or ended complete (``complete``), the
    file it runs (the host's name for it), how far into the file it is (bytes, and the
    host's percentage), the host's estimate of the seconds left, and its message (an
    error's)."""

    state: str
    active: bool
    complete: bool
    file: str | None
    position_bytes: int | None
    completion_pct: float | None = None
    left_s: float | None = None
    message: str = ""


class PrintHost(Protocol):
    """What fabkit asks of a printer host (:mod:`~fabkit.link.host.octoprint`,
    :mod:`~fabkit.link.host.moonraker`); every failure is a one-line FabkitError naming
    the host."""

    default_machine: str
    """The profile for a file whose header names no machine, without --machine."""

    def takes(self, machine: MachineProfile) -> None:
        """Refuse a machine this kind of host cannot drive."""

    def identify(self) -> str:
        """The server and its version (``OctoPrint 1.11.8``); refuses a wrong API key."""

    def check_ready(self) -> None:
        """Refuse a printer that cannot start a job now (not connected, busy)."""

    def upload(self, name: str, data: bytes, select: bool) -> str:
        """Store ``data`` as ``name`` (selected for printing if ``select``); returns the
        host's name for the stored file."""

    def start(self, stored: str) -> None:
        """Start printing the stored file."""

    def status(self) -> JobState:
        """The job now."""

    def pause(self, paused: bool) -> None:
        """Pause (True) or resume (False) the job."""

    def cancel(self) -> None:
        """Cancel the job (the host runs its own cancel procedure)."""


def is_host_url(text: str) -> bool:
    """Whether ``text`` names a printer host (rather than a serial port or pyserial URL)."""
    return text.split("://", 1)[0].lower() in _SCHEMES if "://" in text else False


def parse_host_url(text: str) -> HostURL:
    """``text`` as a :class:`HostURL`; FabkitError for anything else."""
    expected = "expected octoprint+http://HOST:PORT, moonraker+http://HOST:PORT or http://HOST:PORT"
    try:
        parts = urllib.parse.urlsplit(text)
        parts.port  # noqa: B018  (raises ValueError for a bad port)
    except ValueError:
        raise FabkitError(f"--host {text}: not a URL ({expected})") from None
    scheme = parts.scheme.lower()
    if scheme not in _SCHEMES or not parts.hostname:
        raise FabkitError(f"--host {text}: {expected}")
    if parts.username is not None or parts.password is not None:
        raise FabkitError(
            f"--host: put no credentials in the URL; give the API key with {KEY_SOURCES}"
        )
    if parts.query or parts.fragment:
        raise FabkitError(f"--host {text}: a host URL has no query or fragment ({expected})")
    protocol = scheme.rsplit("+", 1)[-1]
    base = f"{protocol}://{parts.netloc}{parts.path.rstrip('/')}"
    return HostURL(_SCHEMES[scheme], base, text)


def resolve_api_key(
    given: str | None, file: str | Path | None, environ: Mapping[str, str] = os.environ
) -> str | None:
    """The API key: ``--api-key``, else the first line of ``--api-key-file``, else the
    environment's :data:`KEY_ENV`, else None. A key a header cannot carry is refused
    without showing it."""
    if given is not None:
        key, source = given, "--api-key"
    elif file is not None:
        try:
            lines = Path(file).read_text(encoding="ascii").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            reason = getattr(exc, "strerror", None) or "not ASCII text"
            raise FabkitError(f"cannot read --api-key-file {file}: {reason}") from None
        key, source = (lines[0].strip() if lines else ""), f"--api-key-file {file}"
    elif environ.get(KEY_ENV):
        key, source = environ[KEY_ENV].strip(), KEY_ENV
    else:
        return None
    if not _KEY.fullmatch(key):
        raise FabkitError(
            f"the API key from {source} is empty or holds blanks or control characters"
        )
    return key


class WebClient:
    """One host's HTTP API: a ``requests`` session with the key header, timeouts, retries
    on idempotent calls (urllib3's Retry), and every call in the log (method, path,
    status, seconds; never a header)."""

    def __init__(
        self, url: HostURL, key: str | None, options: HostOptions, log: TextIO | None = None
    ) -> None:
        import requests
        from requests.adapters import HTTPAdapter
        from urllib3.util.retry import Retry

        self.url, self.has_key, self.options, self.log = url, key is not None, options, log
        self.session = requests.Session()
        if key is not None:
            self.session.headers["X-Api-Key"] = key
        retry = Retry(
            total=options.retries,
            read=min(1, options.retries),  # a server that hangs: once more, not 4 x answer_s
            backoff_factor=0.25,
            status_forcelist=(502, 503, 504),
            allowed_methods=frozenset({"GET", "HEAD"}),
            raise_on_status=False,
        )
        adapter = HTTPAdapter(max_retries=retry)
        self.session.mount("http://", adapter)
        self.session.mount("https://", adapter)
        self.t0 = time.monotonic()

    def close(self) -> None:
        self.session.close()

    def call(
        self, method: str, path: str, *, answer_s: float | None = None, **kwargs: Any
    ) -> requests.Response:
        """``method`` ``path`` (``kwargs`` as requests': params, json, data, files); any
        failure to get an answer is one FabkitError line naming the host."""
        import requests
        from urllib3.exceptions import NewConnectionError
        from urllib3.exceptions import TimeoutError as Urllib3Timeout

        timeout = (self.options.connect_s, answer_s or self.options.answer_s)
        self._log(">>", f"{method} {path}")
        try:
            response = self.session.request(method, self.url.base + path, timeout=timeout, **kwargs)
        except requests.RequestException as exc:
            cause = getattr(exc.args[0], "reason", None) if exc.args else None  # after retries
            late = isinstance(cause, Urllib3Timeout) and not isinstance(cause, NewConnectionError)
            if isinstance(exc, requests.Timeout) or late:  # (urllib3 files refusals as timeouts)
                raise FabkitError(
                    f"{self.url.text}: no answer to {method} {path} within {timeout[1]:g} s: "
                    "check that the server runs and the network"
                ) from None
            found = _ERRNO.search(str(exc))
            reason = found.group(1).strip() if found else type(exc).__name__
            if isinstance(exc, requests.exceptions.SSLError):
                reason = "TLS failed"
            raise FabkitError(
                f"cannot reach {self.url.text} ({reason}): check that the server runs and "
                "the URL is right"
            ) from None
        self._log("<<", f"{response.status_code} {response.reason}")
        return response

    def json(self, response: requests.Response) -> Any:
        """The JSON body of an answer (FabkitError if it has none)."""
        try:
            return response.json()
        except ValueError:
            raise FabkitError(
                f"{self.url.text}: the answer to {response.request.method} "
                f"{self.path_of(response)} is not JSON: is this the right URL?"
            ) from None

    def refused(self, response: requests.Response, fix: str) -> FabkitError:
        """The one line for a call the host refused (status >= 400): what, the status
        and the server's words, then ``fix``."""
        return FabkitError(f"{self.url.text} refused {self.said(response)}: {fix}")

    def said(self, response: requests.Response) -> str:
        """``POST /path (409: the server's words)``."""
        words = server_words(response)
        status = f"{response.status_code}: {words}" if words else str(response.status_code)
        return f"{response.request.method} {self.path_of(response)} ({status})"

    def key_refused(self, response: requests.Response, where: str) -> FabkitError:
        """The one line for a 401 or 403: a wrong key, or none given."""
        if self.has_key:
            return FabkitError(
                f"{self.url.text} refused the API key ({response.status_code}): give a "
                f"valid key ({where}) with {KEY_SOURCES}"
            )
        return FabkitError(
            f"{self.url.text} needs an API key ({response.status_code}): give one ({where}) "
            f"with {KEY_SOURCES}"
        )

    def path_of(self, response: requests.Response) -> str:
        """The API path a response answers (the URL's own path prefix taken off)."""
        return urllib.parse.urlsplit(response.url).path.removeprefix(
            urllib.parse.urlsplit(self.url.base).path
        )

    def _log(self, arrow: str, text: str) -> None:
        if self.log is not None:
            self.log.write(f"{time.monotonic() - self.t0:10.4f} {arrow} {text}\n")


def server_words(response: requests.Response) -> str:
    """What the server said about a refused call, on one line: OctoPrint's ``{"error":
    "..."}``, Moonraker's ``{"error": {"message": "..."}}``, else the reason phrase."""
    try:
        body = response.json()
    except ValueError:
        body = None
    error = body.get("error") if isinstance(body, dict) else None
    if isinstance(error, dict):
        error = error.get("message")
    text = error if isinstance(error, str) and error else response.reason or ""
    return " ".join(text.split())[:200]
