"""Type stubs of the compiled module ``opal._native`` (use the wrappers in ``opal``)."""

from typing import Any, Callable, List, Optional, Sequence, Tuple

__version__: str

class OpalError(ValueError):
    """An Opal error: bad input, unreadable file, failed run (the message is the CLI's)."""

_Progress = Optional[Callable[[str, int, Optional[int]], Any]]

class Scene:
    """A built scene."""

    @property
    def sensors(self) -> List[Tuple[str, int, int]]: ...
    @property
    def path(self) -> str: ...
    def render(
        self,
        spp: Optional[int] = None,
        max_depth: Optional[int] = None,
        sensor: str = "0",
        seed: int = 0,
        threads: Optional[int] = None,
        progress: _Progress = None,
    ) -> Tuple[bytearray, int, int, str]:
        """(little-endian float32 RGB bytes, height, width, report JSON)."""

def load_scene(path: str, defines: Sequence[Tuple[str, str]] = ...) -> Scene: ...
def read_exr(path: str) -> Tuple[bytearray, int, int]: ...
def write_exr(path: str, data: bytes, height: int, width: int) -> None: ...
def run_command(argv: Sequence[str], threads: Optional[int] = None, progress: _Progress = None) -> str:
    """Runs an ``opal`` subcommand in-process; its result as JSON text."""
