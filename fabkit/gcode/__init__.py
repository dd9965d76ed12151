"""The G-code language once: the modal state every reader of a job shares."""
