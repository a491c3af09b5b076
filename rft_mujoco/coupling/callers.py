"""Where a warning of the library should point: the user's line, not the library's.

The library warns from deep inside its own code, often from ``mjcb_control``, which MuJoCo calls from
inside ``mj_step``/``mj_forward`` (C frames leave no Python frame, so the frame above the dispatcher is the
line that called ``mj_step``). A fixed ``stacklevel`` breaks whenever the call path changes (a refactor,
``attach_scene`` around ``attach``, ``kinematic_rollout`` around ``mj_step``); :func:`user_stacklevel`
counts the frames instead.

The frames skipped are those of the library proper: every module of the ``rft_mujoco`` package except
``rft_mujoco.studies``, whose modules are programs that use the library (their ``mj_step`` lines are
what a warning should name, as a user's script's would be).
"""

from __future__ import annotations

import os
import sys

_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LIBRARY_PREFIX = os.path.normcase(_PACKAGE + os.sep)
"""Path prefix of the library's own files (frames skipped by :func:`user_stacklevel`)."""
PROGRAM_PREFIXES = (os.path.normcase(os.path.join(_PACKAGE, "studies") + os.sep),)
"""Path prefixes inside the package that count as the user's code (the studies are programs)."""


def is_library_file(filename: str) -> bool:
    """Whether ``filename`` (a code object's ``co_filename``) is one of the library's own modules."""
    path = os.path.normcase(os.path.abspath(filename))
    return path.startswith(LIBRARY_PREFIX) and not path.startswith(PROGRAM_PREFIXES)


def user_stacklevel(extra: int = 0) -> int:
    """The ``stacklevel`` for :func:`warnings.warn` that names the first frame outside the library.

    Call it in the function that calls ``warnings.warn`` (``extra`` more levels when a helper between
    them calls it). Counts like ``warnings.warn``: 1 is that function, 2 its caller, and so on. When every
    frame is the library's (a thread started by it, say), the outermost frame is named.
    """
    frame = sys._getframe(1 + extra)        # the function that will call warnings.warn
    level = 1
    while frame.f_back is not None and is_library_file(frame.f_code.co_filename):
        frame = frame.f_back
        level += 1
    return level
