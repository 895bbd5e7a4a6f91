#!/usr/bin/env python3
"""Embree 4's closest hits on the rays `sylva bench trace --export DIR` wrote,
the baseline the CPU reference is measured against (benchmarks/README.md).

    pip install embreex numpy        # for this script only; Sylva never uses it
    python3 benchmarks/embree.py DIR [--threads 2] [--repeat 3]

Prints JSON: Mrays/s (best of --repeat), hits, build time. Embree traces the
triangles opaque (no alpha test), so Sylva, which alpha-tests, does more work
per ray: the ratio is conservative against Sylva.
"""
import argparse
import json
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dir")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeat", type=int, default=3)
    a = p.parse_args()
    tris = np.load(f"{a.dir}/triangles.npy").astype(np.float32)
    rays = np.load(f"{a.dir}/rays.npy").astype(np.float32)
    t = time.perf_counter()
    scene = rtcs.EmbreeScene()
    TriangleMesh(scene, tris)
    origins, dirs = np.ascontiguousarray(rays[:, :3]), np.ascontiguousarray(rays[:, 3:])
    scene.run(origins[:1], dirs[:1])  # Embree commits (builds) lazily
    build_s = time.perf_counter() - t
    chunks = np.array_split(np.arange(len(rays)), 64 * a.threads)

    def trace(idx):
        return scene.run(origins[idx], dirs[idx], output=1)["primID"]

    best, hits = float("inf"), 0
    with ThreadPoolExecutor(a.threads) as pool:
        for _ in range(a.repeat):
            t = time.perf_counter()
            prim = np.concatenate(list(pool.map(trace, chunks)))
            best = min(best, time.perf_counter() - t)
            hits = int((prim >= 0).sum())
    print(json.dumps({
        "benchmark": "embree",
        "triangles": len(tris),
        "rays": len(rays),
        "threads": a.threads,
        "build_s": build_s,
        "mrays_per_second": len(rays) / best / 1e6,
        "hits": hits,
    }, indent=2))


if __name__ == "__main__":
    main()
