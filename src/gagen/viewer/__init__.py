"""See the robot move: a live 3-D view in the browser and self-contained HTML playback.

Needs the optional extra `pip install gagen[viewer]` (viser, trimesh, pycollada). The
viewer is a consumer of the runtime: it reads a loaded model's frames with
`dyn.frame_placement` and its description's visuals (`visuals`), and draws them with viser.

    gagen.viewer.write_html(path, dyn, t, q)      # what SimulationResult.to_html calls
    gagen.viewer.start_viewer(dyn, run=(t, q))    # the live view of `python -m gagen view`
    gagen.viewer.read_run(path, dyn)              # (t, q) of a run's CSV, by column names
"""

from __future__ import annotations

from .visuals import MeshWarning

__all__ = ["MeshWarning", "read_run", "require", "start_viewer", "write_html"]

_EXTRA = "pip install 'gagen[viewer]'"


def require() -> None:
    """Raise ImportError naming the extra when the viewer's packages are missing."""
    import importlib.util

    missing = [name for name in ("viser", "trimesh", "collada")
               if importlib.util.find_spec(name) is None]
    if missing:
        raise ImportError(f"the viewer needs {', '.join(missing)}: {_EXTRA}")


def write_html(path, dyn, t, q, p=None, **options):
    """A self-contained HTML playback of a run (or several): `gagen.viewer.html`."""
    require()
    from .html import write_html as write

    return write(path, dyn, t, q, p, **options)


def start_viewer(dyn, **options):
    """The live viewer of a model in the browser: `gagen.viewer.live.start_viewer`."""
    require()
    from .live import start_viewer as start

    return start(dyn, **options)


def read_run(path, dyn):
    """(t, q) of a run's CSV, its columns read by name: `gagen.viewer.runfile`."""
    from .runfile import read_run as read

    return read(path, dyn)
