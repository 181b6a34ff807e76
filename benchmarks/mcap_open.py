"""Opening a recording bounded: what the checks before the first message cost, next to reading every message.

`recording.bounded_mcap.open_bounded` walks the top-level records, inflates every chunk piece by piece to check it
fits in the size it claims, and checks the summary's chunk index; then the reader inflates each chunk again to
read its messages. Recordings of silhouette images (mono8, a blob on black, as the simulated camera sends) at
several sizes, zstd and lz4; medians of REPEATS runs.
Writes docs/figures/mcap_open.json and .png.

    scripts/with_env.sh python benchmarks/mcap_open.py [--sizes 10,40] [--repeats 5]
"""
import argparse
import json
import os
import statistics
import tempfile
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mcap.reader import make_reader  # noqa: E402

from recording.bounded_mcap import open_bounded  # noqa: E402
from recording.mcap_file import RecordingWriter  # noqa: E402

FIGURES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "docs", "figures")
WIDTH = HEIGHT = 480


def silhouette(index: int) -> bytes:
    """A mono8 frame: a disc that moves from frame to frame."""
    y, x = np.mgrid[:HEIGHT, :WIDTH]
    cx, cy = WIDTH / 2 + 100 * np.cos(index / 20), HEIGHT / 2 + 100 * np.sin(index / 20)
    return (((x - cx) ** 2 + (y - cy) ** 2 < 80 ** 2) * 255).astype(np.uint8).tobytes()


def write(path: str, megabytes: float, compression: str) -> int:
    """A recording of ``megabytes`` of raw image data; returns the message count."""
    writer = RecordingWriter(path, compression=compression, chunk_size=4 << 20)
    channel = writer.add_topic("/camera/silhouette", "sensor_msgs/msg/Image")
    count = int(megabytes * 1e6 / (WIDTH * HEIGHT))
    for index in range(count):
        writer.write(channel, silhouette(index), index * 33_000_000, index * 33_000_000)
    writer.close()
    return count


def timed(function) -> float:
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def measure(path: str) -> tuple[float, float]:
    """(seconds to open bounded, seconds to read every message of the opened file)."""
    stream = None

    def open_it():
        nonlocal stream
        stream = open_bounded(path)

    opened = timed(open_it)
    with stream:
        read = timed(lambda: sum(1 for _ in make_reader(stream).iter_messages()))
    return opened, read


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="10,40", help="raw image megabytes per recording, comma-separated")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    runs = []
    with tempfile.TemporaryDirectory() as folder:
        for compression in ("zstd", "lz4"):
            for megabytes in (float(size) for size in args.sizes.split(",")):
                path = os.path.join(folder, f"{compression}-{megabytes:g}.mcap")
                messages = write(path, megabytes, compression)
                samples = [measure(path) for _ in range(args.repeats)]
                opened = statistics.median(s[0] for s in samples)
                read = statistics.median(s[1] for s in samples)
                runs.append({"compression": compression, "raw_mb": megabytes, "messages": messages,
                             "file_mb": round(os.path.getsize(path) / 1e6, 2), "open_s": round(opened, 4),
                             "read_s": round(read, 4), "open_over_read": round(opened / read, 3)})
                print(runs[-1], flush=True)
    result = {"benchmark": "mcap_open", "repeats": args.repeats, "load_average": os.getloadavg(), "runs": runs}
    os.makedirs(FIGURES, exist_ok=True)
    with open(os.path.join(FIGURES, "mcap_open.json"), "w", encoding="utf-8") as out:
        json.dump(result, out, indent=2)
    figure, axis = plt.subplots(figsize=(7, 3.5))
    labels = [f"{r['compression']}\n{r['raw_mb']:g} MB raw" for r in runs]
    positions = np.arange(len(runs))
    axis.bar(positions - 0.2, [r["open_s"] for r in runs], 0.4, label="open (bounds, chunk inflation, index)")
    axis.bar(positions + 0.2, [r["read_s"] for r in runs], 0.4, label="read every message")
    axis.set_xticks(positions, labels)
    axis.set_ylabel("median time [s]")
    axis.set_title("Opening a recording bounded vs reading it")
    axis.legend()
    figure.tight_layout()
    figure.savefig(os.path.join(FIGURES, "mcap_open.png"), dpi=120)
    print(f"wrote {os.path.join(FIGURES, 'mcap_open.json')} and .png")


if __name__ == "__main__":
    main()
