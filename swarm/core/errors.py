"""swarm's errors: SwarmError, the base of every exception swarm raises on purpose (each also derives from the
builtin it has always been, ValueError or RuntimeError, so a handler of that still catches it); and the error of
bad scenario input (a file, a built-in's flags, a faults table): one type everywhere, so the command line turns
every refusal into the same `FILE: KEY: reason` and exit 2. Pure: imports nothing."""


class SwarmError(Exception):
    """The base of every error swarm raises on purpose (`except SwarmError` catches them all, and nothing else):
    bad input (ScenarioError, ProtocolError, ...), a refusal (DriveRefused, RunRefused, ...), a failure of a run
    (SimulationError, NotReady, ...)."""


class ScenarioError(SwarmError, ValueError):
    """A scenario that cannot run. `where` is the file, `key` the dotted key."""

    def __init__(self, where: str, key: str, reason: str):
        self.where, self.key, self.reason = where, key, reason
        super().__init__(f"{where}: {key}: {reason}" if key else f"{where}: {reason}")


def read_text_file(path: str, what: str = "file") -> str:
    """The UTF-8 text of the regular file at `path`, or a ScenarioError that says why not: missing, a
    directory, not a regular file (a FIFO or a device would block or never end), unreadable, not UTF-8."""
    import os
    import stat

    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise ScenarioError(path, "", "no such file") from None
    except OSError as e:
        raise ScenarioError(path, "", f"cannot read: {e.strerror or e}") from None
    if stat.S_ISDIR(st.st_mode):
        raise ScenarioError(path, "", f"is a directory; give {'an' if what[:1] in 'aeiou' else 'a'} {what} in it")
    if not stat.S_ISREG(st.st_mode):
        raise ScenarioError(path, "", "is not a regular file (a FIFO, a device or a socket); give a file")
    try:
        with open(path, "rb") as f:
            raw = f.read()
    except OSError as e:
        raise ScenarioError(path, "", f"cannot read: {e.strerror or e}") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise not_utf8(path, raw, e) from None


def not_utf8(path: str, raw: bytes, e: UnicodeDecodeError) -> ScenarioError:
    """The refusal of a file whose bytes `raw` are not UTF-8 (e: the decoder's error): where the first bad byte is."""
    line = raw[:e.start].count(b"\n") + 1
    return ScenarioError(path, "", f"not UTF-8 text (byte {e.start}, line {line}): a TOML file is UTF-8")

