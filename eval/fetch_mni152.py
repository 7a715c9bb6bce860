"""The whole-brain MNI152 white- and grey-matter probability maps at 1 mm,
from the nilearn wheel on PyPI (the data folder holds a 48-voxel crop of the
first and a 2 mm block mean of the second), for `real_placements.py --only
wm_brain,gm_brain`: the masks `prob > 127.5` at the maps' own grid are the
issue's held-out 1 mm masks (315k and 535k vertices as voxel quads), and the
maps' level sets their truth. Also the T1-weighted template of the same
wheel, for `real_placements.py --only t1_white,t1_pial,...`: its level sets
between white and grey matter and between grey matter and CSF are real
surfaces no setting was tuned on.

    python3 eval/fetch_mni152.py [--dest eval/.mni152]

The maps are MNI ICBM152 2009 (c) McConnell Brain Imaging Centre, shipped in
nilearn (BSD-3); they are data for measuring, not part of the repository
(`eval/.mni152/` is ignored by git).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import wheel_data  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
WHEEL = "nilearn==0.14.1"
# The maps and their SHA-256, so every measurement is of the same data.
MAPS = {
    "mni_icbm152_wm_tal_nlin_sym_09a_converted.nii.gz": "382d92812de4744f9c86c7a0e4f680dc317a0a50e4da1f0153618a6798c7b7db",
    "mni_icbm152_gm_tal_nlin_sym_09a_converted.nii.gz": "97a5ca69bd24db37a9cb7b32525e1733a209af904129bf1cd36da06d24243bed",
    "mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz": "421a10e872fd6cadae7f61d358dffbcc1795a497d61ee76c5dda2503e1a1e9e6",
}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dest", default=str(ROOT / "eval" / ".mni152"))
    args = ap.parse_args()
    wheel_data.fetch(WHEEL, "nilearn/datasets/data", MAPS, Path(args.dest))


if __name__ == "__main__":
    main()
