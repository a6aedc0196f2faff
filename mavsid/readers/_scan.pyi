from typing import Any

vectorised: int

def pairs(data: Any, start: int, stop: int, offsets: Any, types: Any, /) -> tuple[int, int]: ...
def ulog_data(data: Any, start: int, until: int, positions: Any, sizes: Any, ids: Any, /
              ) -> tuple[int, int]: ...
