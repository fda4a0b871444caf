"""What a command's ``--out`` may be, and which of its options name inputs (README "Output folders")."""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["INPUT_OPTIONS", "input_paths", "out_path"]


def out_path(text: str) -> Path:
    """argparse type of ``--out``: a non-empty path (``Path("")`` would silently mean the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a folder name, got an empty one")
    return Path(text)


#: Options whose values are files or folders a run reads: a result folder must neither be nor hold one.
INPUT_OPTIONS = ("drive", "road_profile", "profile", "network", "store", "fleet")


def input_paths(args: argparse.Namespace) -> list[str]:
    """The input files and folders named by ``args`` (:data:`INPUT_OPTIONS`; lists flattened).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of str
    """
    out = []
    for name in INPUT_OPTIONS:
        value = getattr(args, name, None)
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if v is not None:
                out.append(str(v))
    return out
