"""The tracked tree stays small enough to travel to a remote GPU machine with a checkpoint.

``tools/gpu_train.sh`` sends the working tree (tracked files and untracked files git does not
ignore) plus the paths it carries, 64 MiB in all (docs/training.md, weights/README.md). A call
that resumes the full network carries its model-only checkpoint (4 bytes per parameter) and the
wheels the machine lacks (pymunk, cffi, pycparser: 1.3 MiB), so the tracked tree must leave room
for them. This test fails when a commit would take that room (a weights file more, a data file
committed by mistake) and names the largest files; weights/README.md ("What git tracks") says
which weights files are tracked and why.
"""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tpnet_ref.config import TPNetConfig, param_shapes

REPO = Path(__file__).resolve().parent.parent
MIB = 1 << 20
DEVICE_TREE = 64 * MIB
#: the wheels (1.3 MiB), checkpoint.json and log.jsonl, and the torch payload's own overhead
CARRY_EXTRA = 2 * MIB


def carry_reserve() -> int:
    """Bytes a resuming call of the full network carries: its float32 parameters + extras."""
    n = sum(int(np.prod(s)) for s in param_shapes(TPNetConfig()).values())
    return 4 * n + CARRY_EXTRA


def tracked_bytes() -> tuple[int, list[tuple[int, str]]]:
    out = subprocess.run(["git", "-C", str(REPO), "ls-files", "-z"], capture_output=True,
                         check=True).stdout.decode()
    sizes = []
    for name in filter(None, out.split("\0")):
        p = REPO / name
        if os.path.lexists(p):                       # a link counts as the link, not its target
            sizes.append((os.lstat(p).st_size, name))
    return sum(s for s, _ in sizes), sorted(sizes, reverse=True)


def test_the_carry_reserve_is_the_full_networks_model_only_checkpoint():
    # 7,101,756 parameters (docs/training.md): 28.4 MB, the 27.1 MiB model-only payload
    assert 27 * MIB < carry_reserve() - CARRY_EXTRA < 28 * MIB


@pytest.mark.skipif(shutil.which("git") is None or not (REPO / ".git").exists(),
                    reason="not a git checkout")
def test_tracked_tree_leaves_room_for_a_carried_checkpoint():
    total, sizes = tracked_bytes()
    limit = DEVICE_TREE - carry_reserve()
    biggest = ", ".join(f"{n} {s / MIB:.1f} MiB" for s, n in sizes[:5])
    assert total <= limit, (f"the tracked tree is {total / MIB:.1f} MiB, over {limit / MIB:.1f} "
                            f"MiB (64 MiB to a GPU machine less a carried checkpoint); largest: "
                            f"{biggest}")
