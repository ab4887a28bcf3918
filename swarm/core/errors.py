"""The error of bad scenario input (a file, a built-in's flags, a faults table): one type everywhere,
so the command line turns every refusal into the same `FILE: KEY: reason` and exit 2."""


class ScenarioError(ValueError):
    """A scenario that cannot run. `where` is the file, `key` the dotted key."""

    def __init__(self, where: str, key: str, reason: str):
        self.where, self.key, self.reason = where, key, reason
        super().__init__(f"{where}: {key}: {reason}" if key else f"{where}: {reason}")
