"""Select a database from a recorded sequence, write it with hloc's retrieval
pairs and a COLMAP model, and plot the top view of the trajectory with the
database frames.

    python select_and_export.py [SEQUENCE] [OUT]

SEQUENCE defaults to the 7-Scenes sample of ../shared/data; OUT to
./placedb-example.
"""

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt
import numpy as np

import placedb

here = Path(__file__).resolve().parent
seq_path = Path(sys.argv[1]) if len(sys.argv) > 1 else here.parents[1] / "shared" / "data" / "7scenes-1000"
out = Path(sys.argv[2]) if len(sys.argv) > 2 else Path("placedb-example")

seq = placedb.read_sequence(seq_path, max_frames=300)
db = placedb.select(seq, mu=0.3)
print(f"{seq.name}: {len(seq)} frames -> {len(db)} database frames")
print("metrics:", {k: db.metrics[k] for k in ("uncovered", "spatial_coverage", "reduction")})

for line in db.write(out / "database", pairs=out / "pairs.txt", colmap=out / "colmap"):
    print(line)

# Top view: camera positions, database frames marked, coloured by class.
xyz = seq.poses[:, :3, 3]
fig, ax = plt.subplots(figsize=(6, 6))
ax.scatter(xyz[:, 0], xyz[:, 2], c=db.labels, s=4, cmap="tab20")
taken = xyz[db.frames]
ax.scatter(taken[:, 0], taken[:, 2], marker="*", s=80, c="k", label="database frames")
ax.set_xlabel("x (m)")
ax.set_ylabel("z (m)")
ax.set_aspect("equal")
ax.legend()
fig.savefig(out / "topview-matplotlib.png", dpi=100)
print(f"wrote {out}/topview-matplotlib.png")
assert np.all(np.isin(db.labels, db.frames))
