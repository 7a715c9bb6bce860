"""Four more hemibrain neurons, beside the data folder's 722817260, from the
navis wheel on PyPI: olfactory projection neurons of the DA1 glomerulus
(Scheffer et al., eLife 2020), as navis ships them for its examples
(decimated meshes of 6-7k vertices with non-manifold junctions and a few
open edges, like the data folder's neuron). No setting was tuned on them:
`compare_peers.py --navis` measures every tool on them with the same
metrics, so the neuron results can be checked on more than one neuron.

    python3 eval/fetch_navis.py [--dest eval/.navis]

The meshes are data for measuring, not part of the repository
(`eval/.navis/` is ignored by git); the hemibrain data set is CC-BY 4.0
(Janelia Research Campus), navis itself GPL-3.0.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import wheel_data  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
WHEEL = "navis==1.12.0"
# The meshes and their SHA-256, so every measurement is of the same data.
# The wheel's 722817260.obj is the data folder's neuron, byte for byte.
MESHES = {
    "1734350788.obj": "51ea0a4610f69ca350f1ed80cb2cd49accdb35e6168e26640e300367d0289c0c",
    "1734350908.obj": "fc12a9c09e52e2a5b30ad96be29776d2a63139d7a2473723129a1943c169d4d6",
    "754534424.obj": "518612b1af773fbb615194eb7de395c1d295265dafc9b565b886bc84b827963d",
    "754538881.obj": "df96f234fe1984d8db3e47fbdc9b7466e0dca5fc07232a41c5531e2f630cbe49",
}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dest", default=str(ROOT / "eval" / ".navis"))
    args = ap.parse_args()
    wheel_data.fetch(WHEEL, "navis/data/obj", MESHES, Path(args.dest))


if __name__ == "__main__":
    main()
