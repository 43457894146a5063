"""GG-CNN's training and inference speed on this machine, with glibc's default allocation
against :func:`dlsr.memory.reused_heap` (one JSON object on stdout).

A training sample-step (300 x 300 input, batch 8, the paper's network, augmentation and label
maps included) allocates and frees about 100 MB of activations per batch in blocks above
glibc's mmap threshold, each faulted in again 4 kB at a time. Both variants run the same
batches from the same weights in one process, so their losses must be equal (``same_loss``);
``ratio`` is default seconds over reused-heap seconds (> 1: the heap is faster). Per variant:
milliseconds per sample-step (training) and per forward pass (inference, batch 1), user and
system CPU seconds and minor page faults.

Usage: python scripts/bench_ggcnn.py [--batches 30] [--forwards 30] [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import resource
import time

import numpy as np


def _batches(n_batches, n_images=4, size=300, batch=8):
    from graspsim.detectors.ggcnn.maps import grasp_maps
    from graspsim.detectors.ggcnn.train import augment

    rng = np.random.default_rng(0)
    X = rng.normal(size=(n_images, size, size)).astype(np.float32)
    R = [np.array([[size / 2, size / 2, 0.3, 40.0, 20.0]]) for _ in X]
    for b in range(n_batches):
        r = np.random.default_rng([0, b])
        xs, ys = [], []
        for i in r.integers(n_images, size=batch):
            x, rr = augment(X[i], R[i], r)
            xs.append(x)
            ys.append(grasp_maps(rr, (size, size)))
        yield np.stack(xs)[:, None], np.stack(ys)


def _usage():
    u = resource.getrusage(resource.RUSAGE_SELF)
    return time.perf_counter(), u.ru_utime, u.ru_stime, u.ru_minflt


def _measure(torch, reused, n_batches, n_forwards):
    import contextlib

    from dlsr.memory import reused_heap
    from graspsim.detectors.ggcnn.model import FILTERS, build_network

    torch.manual_seed(0)
    net = build_network(FILTERS)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    block = reused_heap() if reused else contextlib.nullcontext()
    out = {}
    with block:
        batches = list(_batches(n_batches + 2))
        for i, (xb, yb) in enumerate(batches):
            if i == 2:  # two warm-up batches
                t0, u0, s0, f0 = _usage()
            pred = net(torch.from_numpy(xb))
            yt = torch.from_numpy(yb)
            loss = sum(torch.nn.functional.mse_loss(pred[:, k], yt[:, k]) for k in range(4))
            opt.zero_grad()
            loss.backward()
            opt.step()
        t1, u1, s1, f1 = _usage()
        samples = n_batches * batches[0][0].shape[0]
        out["train_ms_per_sample"] = round(1000 * (t1 - t0) / samples, 2)
        out["train_user_s"], out["train_sys_s"] = round(u1 - u0, 2), round(s1 - s0, 2)
        out["train_minor_faults"] = int(f1 - f0)
        out["loss"] = float(loss.detach())
        net.eval()
        x = torch.from_numpy(batches[0][0][:1])
        with torch.no_grad():
            net(x)
            t0, u0, s0, f0 = _usage()
            for _ in range(n_forwards):
                net(x)
            t1, u1, s1, f1 = _usage()
        out["forward_ms"] = round(1000 * (t1 - t0) / n_forwards, 2)
        out["forward_minor_faults"] = int(f1 - f0)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--batches", type=int, default=30, help="timed training batches of 8")
    p.add_argument("--forwards", type=int, default=30, help="timed forward passes")
    p.add_argument("--threads", type=int, default=2, help="torch threads")
    args = p.parse_args(argv)
    from graspsim.detectors.ggcnn.model import require_torch

    torch = require_torch()
    torch.set_num_threads(args.threads)
    torch.use_deterministic_algorithms(True)
    default = _measure(torch, False, args.batches, args.forwards)
    heap = _measure(torch, True, args.batches, args.forwards)
    print(json.dumps({
        "torch": torch.__version__, "threads": args.threads, "batches": args.batches,
        "default": default, "reused_heap": heap,
        "ratio_train": round(default["train_ms_per_sample"] / heap["train_ms_per_sample"], 3),
        "ratio_forward": round(default["forward_ms"] / heap["forward_ms"], 3),
        "same_loss": default["loss"] == heap["loss"],
    }, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
