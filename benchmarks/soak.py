"""Soak benchmark: ``cantrack demo`` (stepped) for an hour or more of machine time, fed with
items all the time; RSS, open files, output sizes and tracking error at intervals and at the end.

    python benchmarks/soak.py                          # 1 h of machine time (default)
    nice -n 10 python benchmarks/soak.py --hours 2 --file-size 20000000 --keep 3 --json soak.json

The workload is the demo's (examples/bus/demo.yml: encoder, 4 drives, pick and place) with the
items made alike (fixed pitch 600 mm, no lateral offset, no angle), so that every item is
caught under the same conditions and only the belt's absolute position grows: the tracking
error of the last item must be the first's.  The demo runs as its own process exactly as a
user starts it (``cantrack demo CONFIG --items N --duration S -o DIR --file-size B --keep K``);
this script samples it from outside every ``--every`` seconds of wall time:

- RSS (``/proc/PID/status`` VmRSS) and open file descriptors (``/proc/PID/fd``);
- the output directory: every file's size and count (bus.log and telemetry.jsonl with their
  rotated files);
- machine time and items from the streaming telemetry (``item`` lines: outcome, max tracking
  error while following).

Targets (printed PASS/FAIL): RSS growth <= 20 MB from the end of the warm-up (``--warmup-s``
of machine time, default 300 s) to the end; every output file within the rotation limits
(size <= file size + one line, at most ``keep`` rotated files + the open one); the last placed
item's tracking error equal to the first's (to 1 um); every item placed.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
DEMO = ROOT / "examples" / "bus" / "demo.yml"

#: one line of slack over the size limit (a record is written whole, then the file rotates)
LINE_SLACK = 4096


def soak_config(directory: Path, hours: float) -> Path:
    """demo.yml with alike items and a duration of ``hours`` of machine time."""
    text = DEMO.read_text().replace("../../eds/", str(ROOT / "eds") + "/")
    head, sep, _ = text.partition("\n.demo:")
    assert sep, "examples/bus/demo.yml has no .demo section"
    demo = (f"\n.demo:\n  items: 100000\n  first_item_s: 0.2\n  pitch_mm: [600, 600]\n"
            f"  seed: 7\n  photo_eye: 0.0\n  lateral: [0, 0]\n  angle: [0, 0]\n"
            f"  pick: {{height: 20, dwell_s: 0.15}}\n"
            f"  place: {{position: [550, 330, 80], angle: 0, dwell_s: 0.05}}\n"
            f"  duration_s: {hours * 3600.0 + 1.0:.1f}\n")
    p = directory / "soak.yml"
    p.write_text(head + demo)
    return p


def rss_mb(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def open_files(pid: int) -> int | None:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None


def outputs(directory: Path) -> dict[str, int]:
    return {p.name: p.stat().st_size for p in sorted(directory.iterdir()) if p.is_file()}


class TelemetryTail:
    """Reads the streaming telemetry (and its rotated files) as it grows: machine time and
    the items done.

    The live file is ``telemetry.jsonl``; a rotation renames it (same inode) to a new,
    unique name (python-can's ``telemetry_<date>T<time>_#NNN.jsonl``, never renamed again)
    and starts a new live file.  So the live file is followed by its inode, each rotated file
    by its name: a rotated name seen for the first time is the former live file when its
    inode is one the live file had (read on from there), else a file never seen (read from
    the start).  Inodes alone would not do: retention deletes old files, and the next live
    file may get a deleted file's inode (and its offset: nothing read any more).
    """

    LIVE = "telemetry.jsonl"

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.live_ino: int | None = None
        self.live_off = 0
        #: offsets of the files that were live (inode -> bytes read), until seen rotated
        self.former: dict[int, int] = {}
        self.rotated_seen: set[str] = set()
        self.t_s = 0.0
        self.items: list[dict] = []
        self.run: dict | None = None
        self.end: dict | None = None

    def poll(self) -> None:
        from controller.canopen.io.rotating import rotated_files

        for p in rotated_files(self.directory / self.LIVE):
            if p.name in self.rotated_seen:
                continue
            try:
                ino = p.stat().st_ino
            except OSError:
                continue  # deleted by the retention meanwhile
            start = self.former.pop(ino, 0)
            if ino == self.live_ino:  # (renamed since the last poll)
                start, self.live_ino = self.live_off, None
            self._read(p, start)
            self.rotated_seen.add(p.name)
        live = self.directory / self.LIVE
        try:
            ino = live.stat().st_ino
        except OSError:
            return
        if ino != self.live_ino:
            if self.live_ino is not None:
                self.former[self.live_ino] = self.live_off
            self.former.pop(ino, None)  # (an inode used again: a new file)
            self.live_ino, self.live_off = ino, 0
        self.live_off = self._read(live, self.live_off)

    def _read(self, path: Path, offset: int) -> int:
        """Parse the whole lines of ``path`` from ``offset``; the offset after them."""
        try:
            with open(path, "rb") as f:
                f.seek(offset)
                data = f.read()
        except OSError:
            return offset  # rotated away meanwhile (read under its new name)
        end = data.rfind(b"\n") + 1  # only whole lines
        for line in data[:end].splitlines():
            try:
                d = json.loads(line)
            except ValueError:
                continue
            kind = d.get("type")
            if kind in ("cycle", "status") and d.get("t_s") is not None:
                self.t_s = max(self.t_s, float(d["t_s"]))
            elif kind == "item" and d.get("outcome") in ("placed", "missed"):
                self.items.append(d)
                t = d.get("t_s")
                if t is not None:
                    self.t_s = max(self.t_s, float(t))
            elif kind == "run":
                self.run = d
            elif kind == "end":
                self.end = d
                if d.get("t_s") is not None:
                    self.t_s = max(self.t_s, float(d["t_s"]))
        return offset + end


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--hours", type=float, default=1.0, help="machine time [h] (default 1)")
    p.add_argument("--every", type=float, default=30.0, help="sample every S of wall time")
    p.add_argument("--warmup-s", type=float, default=300.0,
                   help="machine time before the RSS reference is taken (default 300 s)")
    p.add_argument("--file-size", type=int, default=50_000_000,
                   help="rotate bus.log and telemetry.jsonl at this size [bytes] (default 50 MB)")
    p.add_argument("--keep", type=int, default=2, help="rotated files kept (default 2)")
    p.add_argument("-o", "--output", help="output directory (default: a temporary one)")
    p.add_argument("--json", metavar="FILE", help="every sample and figure as JSON")
    args = p.parse_args(argv)
    tmp = tempfile.TemporaryDirectory()
    work = Path(tmp.name)
    out = Path(args.output) if args.output else work / "out"
    out.mkdir(parents=True, exist_ok=True)
    cfg = soak_config(work, args.hours)
    cmd = [sys.executable, "-m", "controller.cli", "demo", str(cfg), "-o", str(out),
           "--no-plot", "-q", "--file-size", str(args.file_size), "--keep", str(args.keep)]
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs, load average "
          f"{os.getloadavg()[0]:.2f}, nice {os.nice(0)}; {args.hours:g} h of machine time; "
          f"rotation at {args.file_size} bytes, keep {args.keep}")
    print(" ".join(cmd))
    wall0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=str(work), env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    tail = TelemetryTail(out)
    samples: list[dict] = []
    max_sizes: dict[str, int] = {}
    max_files = 0
    print(f"{'wall s':>8}{'machine s':>11}{'RSS MB':>9}{'fds':>6}{'files':>7}{'output MB':>11}"
          f"{'items':>7}{'last err mm':>13}")
    try:
        while True:
            done = proc.poll() is not None
            tail.poll()
            sizes = outputs(out)
            for name, size in sizes.items():
                max_sizes[name] = max(size, max_sizes.get(name, 0))
            max_files = max(max_files, len(sizes))
            s = {"wall_s": time.perf_counter() - wall0, "machine_s": tail.t_s,
                 "rss_mb": rss_mb(proc.pid), "open_files": open_files(proc.pid),
                 "files": len(sizes), "output_bytes": sum(sizes.values()),
                 "items": len(tail.items),
                 "last_error_mm": tail.items[-1].get("max_error_mm") if tail.items else None}
            if not done:
                samples.append(s)
                print(f"{s['wall_s']:8.0f}{s['machine_s']:11.1f}"
                      f"{(s['rss_mb'] or float('nan')):9.1f}{(s['open_files'] or 0):6d}"
                      f"{s['files']:7d}{s['output_bytes'] / 1e6:11.1f}{s['items']:7d}"
                      + (f"{s['last_error_mm']:13.6f}" if s["last_error_mm"] is not None
                         else f"{'-':>13}"), flush=True)
            if done:
                break
            try:
                proc.wait(timeout=args.every)
            except subprocess.TimeoutExpired:
                pass
    except KeyboardInterrupt:
        proc.terminate()
        proc.wait()
    stdout, stderr = proc.communicate()
    tail.poll()
    wall = time.perf_counter() - wall0
    print(f"\nexit code {proc.returncode}, {wall:.0f} s wall")
    if proc.returncode != 0:
        print(stderr[-3000:])
    print("\n".join(stdout.splitlines()[-6:]))
    # figures
    warm = [s for s in samples if s["machine_s"] >= args.warmup_s and s["rss_mb"] is not None]
    rss_ref = warm[0]["rss_mb"] if warm else None
    rss_end = warm[-1]["rss_mb"] if warm else None
    rss_max = max((s["rss_mb"] for s in warm), default=None)
    growth = (rss_max - rss_ref) if warm else None
    placed = [i for i in tail.items if i.get("outcome") == "placed"]
    missed = [i for i in tail.items if i.get("outcome") == "missed"]
    first = placed[0].get("max_error_mm") if placed else None
    last = placed[-1].get("max_error_mm") if placed else None
    limit = args.file_size + LINE_SLACK
    too_big = {n: s for n, s in max_sizes.items() if s > limit}
    groups: dict[str, int] = {}
    for name in outputs(out):
        groups[name.split(".")[0]] = groups.get(name.split(".")[0], 0) + 1
    too_many = {g: n for g, n in groups.items() if n > args.keep + 1}
    print(f"machine time {tail.t_s:.0f} s ({tail.t_s / 3600:.2f} h) in {wall:.0f} s wall")
    if warm:
        print(f"RSS after warm-up ({args.warmup_s:g} s) {rss_ref:.1f} MB, at the end "
              f"{rss_end:.1f} MB, max {rss_max:.1f} MB: growth {growth:+.1f} MB")
    print(f"open files: first {samples[0]['open_files'] if samples else '-'}, last "
          f"{samples[-1]['open_files'] if samples else '-'}, max "
          f"{max((s['open_files'] or 0 for s in samples), default=0)}")
    print("output files at the end: " + ", ".join(f"{n} {s / 1e6:.1f} MB"
                                                 for n, s in outputs(out).items()))
    print("largest size seen per file: " + ", ".join(f"{n} {s / 1e6:.1f} MB"
                                                    for n, s in max_sizes.items()))
    print(f"items placed {len(placed)}, missed {len(missed)}; tracking error while following, "
          f"first item {first} mm, last item {last} mm")
    ok_rss = growth is not None and growth <= 20.0 and tail.t_s >= 3600.0 * min(args.hours, 1.0)
    ok_files = not too_big and not too_many
    ok_err = first is not None and last is not None and abs(last - first) <= 1e-3
    ok_items = bool(placed) and not missed and proc.returncode == 0
    print(f"target RSS growth <= 20 MB over >= 1 h of machine time: "
          f"{'PASS' if ok_rss else 'FAIL'}")
    print(f"target files within rotation limits ({args.file_size} B + a line, <= {args.keep} "
          f"rotated): {'PASS' if ok_files else 'FAIL'} {too_big or ''}{too_many or ''}")
    print(f"target last item's tracking error = first's (1 um): {'PASS' if ok_err else 'FAIL'}")
    print(f"every item placed, exit 0: {'PASS' if ok_items else 'FAIL'}")
    if args.json:
        Path(args.json).write_text(json.dumps({
            "samples": samples, "max_sizes": max_sizes, "items": tail.items,
            "rss_growth_mb": growth, "machine_s": tail.t_s, "wall_s": wall,
            "exit_code": proc.returncode}, indent=1))
    tmp.cleanup()
    return 0 if ok_rss and ok_files and ok_err and ok_items else 1


if __name__ == "__main__":
    sys.exit(main())
