"""Safe outputs and provenance: atomic writes, package versions, input hashes."""

from __future__ import annotations

import json
import os
import platform
import sys
from importlib import metadata
from pathlib import Path

#: Packages whose versions every result records.
PROVENANCE_PACKAGES = ("bayesdamper", "numpy", "scipy", "emcee", "arviz", "numba", "matplotlib", "corner")


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path``, fsync it, then rename over ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def atomic_write_json(path: Path, obj) -> None:
    """Write ``obj`` as indented JSON, atomically."""
    atomic_write_bytes(path, (json.dumps(obj, indent=2, allow_nan=True) + "\n").encode())


def save_figure(fig, stem: Path, formats: tuple[str, ...] = ("png", "pdf"), tight: bool = True) -> list[Path]:
    """Save a Matplotlib figure as ``stem.png`` and ``stem.pdf``, each atomically.

    ``tight=False`` skips the tight bounding-box pass (~0.2 s a figure) for figures whose margins are
    already set by hand (the per-transient corner and trace plots).
    """
    import io

    import matplotlib.pyplot as plt

    out = []
    for fmt in formats:
        buf = io.BytesIO()
        fig.savefig(buf, format=fmt, dpi=120, bbox_inches="tight" if tight else None)
        path = Path(f"{stem}.{fmt}")
        atomic_write_bytes(path, buf.getvalue())
        out.append(path)
    plt.close(fig)
    return out


def versions() -> dict[str, str]:
    """Versions of Python and of the packages a result depends on."""
    out = {"python": sys.version.split()[0], "platform": platform.platform()}
    for name in PROVENANCE_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out
