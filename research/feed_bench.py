"""research/bench --feed: how fast the Python feed turns scenes of a log into training tensors.

Run through research/bench --feed (Debian's /usr/bin/python3, PYTHONPATH=build/python). Without
--log it first records one: a generator of --config publishes --count scenes and a reliable
stackgen.Stream appends every one to the log (nothing lost, unlike a UDP logger), and the
generator's own scenes/s is kept for the comparison. Then, per configuration, it reads the whole
log --runs times through stackgen.torch.StreamDataset (image tensor, boxes, labels, masks and the
rest of the target) and prints each run's scenes/s, counted from the first sample to the last
(so the start of the DataLoader workers is left out), and the medians.
"""

import argparse
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def record(config, count, path, stackgen_bin):
    """Records `count` scenes of `config` into `path`; returns the generator's scenes/s."""
    import stackgen

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("", 0))
        url = "udpm://239.255.76.67:%d?ttl=0&recv_buf_size=4194304" % probe.getsockname()[1]
    recorder = stackgen.LogRecorder(path)
    with stackgen.Stream(url, reliable=True, window=64, count=count, timeout=120) as stream:
        generator = subprocess.Popen([stackgen_bin, "--config", config, "--count", str(count),
                                      "--seed", "1", "--lcm-url", url],
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        for scene in stream:
            recorder.append(scene)
    output, _ = generator.communicate(timeout=120)
    if generator.returncode != 0:
        sys.exit("research/bench: stackgen failed while recording the log")
    found = re.search(r"\(([0-9.]+) scenes/s\)", output)
    return float(found.group(1)) if found else None


def measure(url, workers, augment, batch_size):
    """scenes/s from the first sample to the last of one pass over the log."""
    from torch.utils.data import DataLoader

    import stackgen.torch as sgt

    dataset = sgt.StreamDataset(url, augment=sgt.Augment() if augment else None)
    loader = DataLoader(dataset, batch_size=batch_size, num_workers=workers,
                        collate_fn=sgt.collate)
    samples, start = 0, None
    for images, targets in loader:
        if start is None:
            start = time.perf_counter()
            first = len(images)
        samples += len(images)
        # what a training loop touches: the tensors exist, with masks
        assert targets[0]["masks"].dtype.is_floating_point is False
    return (samples - first) / (time.perf_counter() - start), samples


def main():
    parser = argparse.ArgumentParser(prog="research/bench --feed")
    parser.add_argument("--log", help="an LCM log of scenes (default: record one)")
    parser.add_argument("--config", default=os.path.join(ROOT, "config", "default.pbtxt"))
    parser.add_argument("--count", type=int, default=100)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--workers", default="0,2",
                        help="DataLoader worker counts to measure, comma-separated")
    parser.add_argument("--batch-size", type=int, default=4)
    parser.add_argument("--stackgen", default=os.path.join(ROOT, "build", "bin", "stackgen"))
    args = parser.parse_args()

    generator_rate = None
    scratch = None
    log = args.log
    if log is None:
        scratch = tempfile.TemporaryDirectory(prefix="stackgen-feed-bench.")
        log = os.path.join(scratch.name, "feed.lcmlog")
        print("recording %d scenes of %s ..." % (args.count, os.path.relpath(args.config)),
              flush=True)
        generator_rate = record(args.config, args.count, log, args.stackgen)
    import stackgen
    first = next(iter(stackgen.Stream("file://" + os.path.abspath(log), count=1)))
    print("log: %s, %dx%d, %d instances in its first scene, %.1f MB" % (
        log, first.width, first.height, first.num_instances, os.path.getsize(log) / 1e6))
    url = "file://" + os.path.abspath(log)
    results = []
    for workers in (int(w) for w in args.workers.split(",")):
        for augment in (False, True):
            rates = []
            for run in range(args.runs):
                rate, samples = measure(url, workers, augment, args.batch_size)
                rates.append(rate)
            name = "%d workers, %s" % (workers, "augmented" if augment else "not augmented")
            print("%-28s runs: %s scenes/s (%d samples each)" % (
                name, ", ".join("%.1f" % r for r in rates), samples), flush=True)
            results.append((name, statistics.median(rates)))
    print("median of %d runs, batch %d, image float32 + target with masks:" % (args.runs,
                                                                              args.batch_size))
    for name, rate in results:
        ratio = " (%.0fx the generator's %.2f scenes/s)" % (
            rate / generator_rate, generator_rate) if generator_rate else ""
        print("  %-28s %.1f scenes/s%s" % (name, rate, ratio))


if __name__ == "__main__":
    main()
