# world/_referee.c: world.referee.pair_scan, compiled
from typing import Any

def pair_scan(q: Any, r: Any, R: Any, live: Any, obstacles: Any,
              freezes: bool) -> tuple[float, float, list[tuple[int, int]], bytes]: ...
