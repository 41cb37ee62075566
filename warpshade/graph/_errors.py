"""The error of a graph that cannot run."""

from ..methods.stage import StageError

__all__: list[str] = []


class GraphError(StageError):
    """A graph that cannot run; the message names the graph file, stage, port or key at fault."""
