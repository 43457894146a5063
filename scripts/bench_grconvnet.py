"""GR-ConvNet's training and inference cost on this machine at k = 32 (the paper's) and k = 16,
beside GG-CNN in the same run (one JSON object on stdout).

Each network trains the same synthetic batches as ``graspsim train`` would build them (batch 8,
its augmentation and label maps, its loss, Adam, deterministic algorithms, activations kept on
the heap), GR-ConvNet at 224 x 224 RGB-D, GG-CNN at 300 x 300 depth, in the default (NCHW)
layout and in the channels-last one the training uses (``speedup_vs_contiguous``). Reported per
network and layout: seconds per batch and per sample-step (wall), the process's CPU seconds per
sample-step (user + system: less sensitive to other processes on the cores than wall time,
though not immune), milliseconds per forward pass (batch 1, eval mode), the parameter count,
and ``vs_ggcnn`` (wall seconds per sample-step over GG-CNN's in the same layout). The
machine's load average before and after is recorded: other processes sharing the cores inflate
the wall times.

Usage: nice -n 5 python scripts/bench_grconvnet.py [--batches 8] [--forwards 10] [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time

import numpy as np


def _batches(spec, n_batches, size, batch=8, n_images=4):
    from graspsim.detectors.ggcnn.maps import grasp_maps
    from graspsim.detectors.ggcnn.train import augment

    rng = np.random.default_rng(0)
    X = rng.normal(size=(n_images, spec.in_channels, size, size)).astype(np.float32)
    R = [np.array([[size / 2, size / 2, 0.3, 40.0, 20.0]]) for _ in X]
    for b in range(n_batches):
        r = np.random.default_rng([0, b])
        xs, ys = [], []
        for i in r.integers(n_images, size=batch):
            x, rr = augment(X[i], R[i], r, spec.rotate, spec.zoom, spec.keep)
            xs.append(x)
            ys.append(grasp_maps(rr, (size, size), spec.width_scale(size),
                                 clip_width=spec.width == "half"))
        yield np.stack(xs), np.stack(ys)


def _cpu():
    u = resource.getrusage(resource.RUSAGE_SELF)
    return time.perf_counter(), u.ru_utime + u.ru_stime


def _measure(torch, network, arch, size, n_batches, n_forwards, memory_format):
    from dlsr.memory import reused_heap
    from graspsim.detectors.ggcnn.model import n_parameters, network_of

    spec = network_of(network)
    torch.manual_seed(0)
    fmt = getattr(torch, memory_format)
    net = spec.build(arch).to(memory_format=fmt)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    loss_fn = (torch.nn.functional.mse_loss if spec.loss == "mse"
               else torch.nn.functional.smooth_l1_loss)
    out = {"network": network, **arch, "input_size": size, "memory_format": memory_format,
           "parameters": n_parameters(net)}
    with reused_heap():
        net.train()
        t0 = c0 = None
        steps = 0
        for i, (xb, yb) in enumerate(_batches(spec, n_batches + 1, size)):
            if i == 1:  # one warm-up batch
                t0, c0 = _cpu()
            pred = net(torch.from_numpy(xb).contiguous(memory_format=fmt))
            yt = torch.from_numpy(yb)
            loss = sum(loss_fn(pred[:, k], yt[:, k]) for k in range(4))
            opt.zero_grad()
            loss.backward()
            opt.step()
            steps += len(xb) if i >= 1 else 0
        t1, c1 = _cpu()
        out["s_per_batch"] = round((t1 - t0) / n_batches, 3)
        out["s_per_sample_step"] = round((t1 - t0) / steps, 4)
        out["cpu_s_per_sample_step"] = round((c1 - c0) / steps, 4)
        net.eval()
        x = torch.from_numpy(xb[:1]).contiguous(memory_format=fmt)
        with torch.no_grad():
            net(x)
            t0, _ = _cpu()
            for _ in range(n_forwards):
                net(x)
            t1, _ = _cpu()
        out["forward_ms"] = round(1000 * (t1 - t0) / n_forwards, 1)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--batches", type=int, default=8, help="timed training batches of 8")
    p.add_argument("--forwards", type=int, default=10, help="timed forward passes")
    p.add_argument("--threads", type=int, default=2, help="torch threads")
    args = p.parse_args(argv)
    from graspsim.detectors.ggcnn.backend import require_torch
    from graspsim.detectors.ggcnn.model import FILTERS

    torch = require_torch()
    torch.set_num_threads(args.threads)
    torch.use_deterministic_algorithms(True)
    load_before = os.getloadavg()
    runs = [("ggcnn", {"filters": list(FILTERS)}, 300),
            ("grconvnet", {"channels": 16, "dropout": 0.1}, 224),
            ("grconvnet", {"channels": 32, "dropout": 0.1}, 224)]
    rows = [_measure(torch, n, a, s, args.batches, args.forwards, f)
            for n, a, s in runs for f in ("contiguous_format", "channels_last")]
    ref = {r["memory_format"]: r["s_per_sample_step"] for r in rows[:2]}
    for i, r in enumerate(rows):
        r["vs_ggcnn"] = round(r["s_per_sample_step"] / ref[r["memory_format"]], 2)
        if r["memory_format"] == "channels_last":
            # the training's layout (graspsim.detectors.ggcnn.train) against the default one
            r["speedup_vs_contiguous"] = round(rows[i - 1]["s_per_sample_step"]
                                               / r["s_per_sample_step"], 2)
    print(json.dumps({
        "torch": torch.__version__, "threads": args.threads, "batches": args.batches,
        "cpus": os.cpu_count(), "load_average_before": [round(v, 2) for v in load_before],
        "load_average_after": [round(v, 2) for v in os.getloadavg()],
        "nice": os.nice(0), "runs": rows,
        "k32_over_k16": round(rows[5]["s_per_sample_step"] / rows[3]["s_per_sample_step"], 2),
    }, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
