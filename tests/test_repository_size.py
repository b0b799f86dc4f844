"""The tracked tree stays small enough to travel to a remote GPU machine with a run's state.

``tools/gpu_train.sh`` sends the working tree (tracked files and untracked files git does not
ignore) plus the paths it carries, 64 MiB in all (docs/training.md, weights/README.md). A run's
state does not travel as one checkpoint: ``gpu_train.sh stage`` cuts it into bundles of at most
``UP_MIB`` MiB (its default read from the script, 21), one a call, and each call carries one
bundle and the wheels the machine lacks (pymunk, cffi, pycparser: 1.3 MiB), so the tracked tree
must leave room for a bundle and the wheels: 64 - 21 - 2 = 41 MiB. 21 MiB cuts the full size's
state into as many bundles (device calls) as 24 MiB did: 4. This test fails when a
commit would take that room (a weights file more, a data file committed by mistake) and names
the largest files; weights/README.md ("What git tracks") says which weights files are tracked
and why.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
MIB = 1 << 20
DEVICE_TREE = 64 * MIB
#: the wheels (1.3 MiB), checkpoint.json, log.jsonl and the manifest the first bundle holds
CARRY_EXTRA = 2 * MIB


def up_mib() -> int:
    """The default size of a staged bundle, MiB: ``UP_MIB=${UP_MIB:-N}`` in tools/gpu_train.sh."""
    text = (REPO / "tools" / "gpu_train.sh").read_text()
    found = re.search(r"\bUP_MIB=\$\{UP_MIB:-(\d+)\}", text)
    assert found, "tools/gpu_train.sh sets no default UP_MIB=${UP_MIB:-N}"
    return int(found.group(1))


def carry_reserve() -> int:
    """Bytes a call carries besides the tree: one bundle of the run's state (``UP_MIB`` MiB,
    staged by ``gpu_train.sh stage``) and the extras."""
    return up_mib() * MIB + CARRY_EXTRA


def tracked_bytes() -> tuple[int, list[tuple[int, str]]]:
    out = subprocess.run(["git", "-C", str(REPO), "ls-files", "-z"], capture_output=True,
                         check=True).stdout.decode()
    sizes = []
    for name in filter(None, out.split("\0")):
        p = REPO / name
        if os.path.lexists(p):                       # a link counts as the link, not its target
            sizes.append((os.lstat(p).st_size, name))
    return sum(s for s, _ in sizes), sorted(sizes, reverse=True)


def test_the_carry_reserve_is_one_staged_bundle_and_the_wheels():
    # a run's state goes up in bundles of UP_MIB (21 MiB), one a call, with the wheels
    assert up_mib() == 21
    assert carry_reserve() == 23 * MIB
    assert DEVICE_TREE - carry_reserve() == 41 * MIB


def full_size_state_bytes() -> int:
    """The full size's run state as `tpnet train run` checkpoints it (`.gpu/m4`): the weights and
    Adam's two moments, float32 each (12 bytes a parameter; 85,372,351 bytes at step 9,724, of
    which 151,279 are torch's framing), plus 1 MiB for that framing."""
    import numpy as np
    from tpnet_ref.config import TPNetConfig, param_shapes
    n = sum(int(np.prod(s)) for s in param_shapes(TPNetConfig()).values())
    assert n == 7_101_756
    return 12 * n + MIB


def test_the_bundle_size_costs_no_device_call():
    # a smaller bundle leaves the tree more room only while the full size's state still goes up
    # in as many calls as at 24 MiB; one more bundle would be one more device call a lease
    state = full_size_state_bytes()
    calls = -(-state // (up_mib() * MIB))
    assert calls == -(-state // (24 * MIB)) == 4


@pytest.mark.skipif(shutil.which("git") is None or not (REPO / ".git").exists(),
                    reason="not a git checkout")
def test_tracked_tree_leaves_room_for_a_staged_bundle():
    total, sizes = tracked_bytes()
    limit = DEVICE_TREE - carry_reserve()
    biggest = ", ".join(f"{n} {s / MIB:.1f} MiB" for s, n in sizes[:5])
    assert total <= limit, (f"the tracked tree is {total / MIB:.1f} MiB, over {limit / MIB:.1f} "
                            f"MiB (64 MiB to a GPU machine less a staged bundle and the "
                            f"wheels); largest: "
                            f"{biggest}")
