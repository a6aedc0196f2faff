"""Start-up cost of the command line against a bare interpreter, in fresh processes; and
the whole ``mavsid fit`` of a big log against a previous checkout, in the same run.

    python benchmarks/bench_startup.py [--runs 5]
    python benchmarks/bench_startup.py --log ../shared/logs/sitl/flightA_mixer.BIN \
        [--baseline DIR | --baseline-rev REV] [--runs 5]

Without ``--log``: min and median wall time of ``python -c pass``, ``mavsid --version``,
``mavsid --help`` and ``mavsid fit`` on the small bundled fixture, and each one's excess over
the bare interpreter (what importing mavsid costs), cold and warm (first run vs the rest).

With ``--log``: ``mavsid fit LOG`` and ``mavsid fit LOG --rrd --report`` (written to a
temporary directory), min / median / max of ``--runs`` fresh processes, with the bare
interpreter's time beside; with ``--baseline DIR`` (a checkout of the previous release, e.g.
``git clone -b main . /tmp/mavsid-base``) or ``--baseline-rev REV`` (that commit of this
repository, exported to a temporary folder with ``git archive``; its compiled extensions
copied from this tree where their C source is the same, else built there) the same commands
from that tree, run alternately with this one's (a busy machine slows both alike), and the
ratio of the medians of wall and of CPU time (user + system of the process and of the
report worker it waits for; steadier than wall time when other work shares the machine).

Bytecode: ``pip install .`` (the README's install) compiles every module to bytecode once, at
install; a checkout run with ``PYTHONDONTWRITEBYTECODE=1`` set (as on some CI machines)
compiles mavsid's ~20 000 lines again in every process (~0.2 s). By default each tree is
compiled once beforehand into a temporary ``PYTHONPYCACHEPREFIX`` (the checkout is left
untouched), so the runs get what an installed mavsid gets; ``--no-bytecode`` times the
compile-every-run case instead.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _env(root: Path, cache: str | None) -> dict[str, str]:
    """The children's environment: ``root`` on the path; with ``cache``, bytecode read from
    (and written to) that folder, compiled there beforehand (see the module's *Bytecode*)."""
    env = {**os.environ, "PYTHONPATH": str(root)}
    if cache is None:
        env["PYTHONDONTWRITEBYTECODE"] = "1"
        return env
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPYCACHEPREFIX"] = cache
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(root / "mavsid")],
                   env=env, check=True)
    return env


def _time(argv: list[str], runs: int, env: dict[str, str]) -> list[float]:
    out = []
    for _ in range(runs):
        t = time.perf_counter()
        subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, check=False)
        out.append(time.perf_counter() - t)
    return out


def _exported(rev: str, into: Path) -> Path:
    """Commit ``rev`` of this repository as a tree in ``into``, ready to run: ``mavsid/``
    from ``git archive``, each compiled extension copied from this tree when its C source
    is the same at ``rev``, else built there (``setup.py build_ext --inplace``)."""
    archive = subprocess.run(["git", "archive", rev, "mavsid", "setup.py", "pyproject.toml"],
                             cwd=ROOT, capture_output=True, check=True).stdout
    into.mkdir(parents=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    build = False
    for source in sorted((into / "mavsid").rglob("*.c")):
        here = ROOT / source.relative_to(into)
        built = sorted(here.parent.glob(f"{source.stem}.*.so"))
        if here.exists() and built and here.read_bytes() == source.read_bytes():
            for so in built:
                shutil.copy2(so, source.parent / so.name)
        else:
            build = True
    if build:
        subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=into,
                       check=True, capture_output=True)
    return into


def _whole_fit(log: str, baseline: str | None, runs: int, bytecode: bool) -> None:
    """``fit LOG`` and ``fit LOG --rrd --report`` from this checkout (and ``baseline``)."""
    trees = {"this": ROOT} | ({"baseline": Path(baseline).resolve()} if baseline else {})
    log = str(Path(log).resolve())  # (each tree runs in its own folder)
    with tempfile.TemporaryDirectory() as tmp:
        envs = {tree: _env(root, str(Path(tmp) / f"pyc-{tree}") if bytecode else None)
                for tree, root in trees.items()}
        cases = {"fit LOG": ["fit", log, "--quiet"],
                 "fit LOG --rrd --report": ["fit", log, "--quiet", "--rrd",
                                            str(Path(tmp) / "o.rrd"), "--report",
                                            str(Path(tmp) / "o.html")]}
        bare = _time([sys.executable, "-c", "pass"], runs, envs["this"])
        times: dict[tuple[str, str], list[float]] = {}
        cpu: dict[tuple[str, str], list[float]] = {}
        for run in range(runs):  # alternate the trees: load on the machine hits both alike
            for case, argv in cases.items():
                # and which goes first: the second of a pair ran up to 1.25x slower (the
                # same tree as both, SITL flight, plain fit: 1.49 against 1.87 s median)
                order = list(trees.items())
                for tree, root in order[::-1] if run % 2 else order:
                    env = envs[tree]
                    u0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                    t = time.perf_counter()
                    proc = subprocess.run([sys.executable, "-m", "mavsid", *argv], cwd=root,
                                          env=env, capture_output=True, check=False)
                    times.setdefault((case, tree), []).append(time.perf_counter() - t)
                    u1 = resource.getrusage(resource.RUSAGE_CHILDREN)
                    cpu.setdefault((case, tree), []).append(
                        u1.ru_utime - u0.ru_utime + u1.ru_stime - u0.ru_stime)
                    if proc.returncode:
                        raise SystemExit(f"{tree}: {' '.join(argv)}: exit {proc.returncode}: "
                                         f"{proc.stderr.decode()[-300:]}")
    print(f"{Path(log).name}, {runs} fresh processes each; python -c pass "
          f"{statistics.median(bare):.3f} s median; "
          + ("bytecode compiled beforehand" if bytecode else "compiled in every run"))
    print(f"{'command':24} {'tree':9} {'min':>7} {'median':>7} {'max':>7} {'CPU med':>8}  ratio "
          "(wall, CPU medians)")
    for case in cases:
        for tree in trees:
            ts, cs = times[(case, tree)], cpu[(case, tree)]
            ratio = ""
            if tree == "this" and baseline:
                base = statistics.median(times[(case, "baseline")])
                base_cpu = statistics.median(cpu[(case, "baseline")])
                ratio = (f"{base / statistics.median(ts):.2f}x / "
                         f"{base_cpu / statistics.median(cs):.2f}x faster than the baseline")
            print(f"{case:24} {tree:9} {min(ts):7.3f} {statistics.median(ts):7.3f} "
                  f"{max(ts):7.3f} {statistics.median(cs):8.3f}  {ratio}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--log", help="time the whole `mavsid fit` of this log instead")
    ap.add_argument("--baseline", metavar="DIR", help="with --log: a checkout to compare with")
    ap.add_argument("--baseline-rev", metavar="REV",
                    help="with --log: this repository's commit REV to compare with")
    ap.add_argument("--no-bytecode", action="store_true",
                    help="compile mavsid in every run (PYTHONDONTWRITEBYTECODE=1)")
    args = ap.parse_args()
    runs = args.runs
    if args.log:
        if args.baseline_rev:
            with tempfile.TemporaryDirectory() as tmp:
                base = _exported(args.baseline_rev, Path(tmp) / "baseline")
                print(f"baseline: {args.baseline_rev} "
                      + subprocess.run(["git", "log", "-1", "--format=%h %s", args.baseline_rev],
                                       cwd=ROOT, capture_output=True, text=True).stdout.strip())
                _whole_fit(args.log, str(base), runs, not args.no_bytecode)
            return
        _whole_fit(args.log, args.baseline, runs, not args.no_bytecode)
        return
    py = [sys.executable]
    cases = {
        "python -c pass": [*py, "-c", "pass"],
        "mavsid --version": [*py, "-m", "mavsid.cli", "--version"],
        "mavsid --help": [*py, "-m", "mavsid.cli", "--help"],
        "mavsid fit sysid_roll.bin": [*py, "-m", "mavsid.cli", "fit",
                                      str(ROOT / "fixtures" / "sysid_roll.bin")],
    }
    with tempfile.TemporaryDirectory() as tmp:
        env = _env(ROOT, None if args.no_bytecode else str(Path(tmp) / "pyc"))
        times = {name: _time(argv, runs, env) for name, argv in cases.items()}
    bare = min(times["python -c pass"])
    print("bytecode " + ("compiled in every run" if args.no_bytecode else "compiled beforehand"))
    print(f"{'command':28} {'cold':>7} {'min':>7} {'median':>7}  beyond the interpreter")
    for name, ts in times.items():
        print(f"{name:28} {ts[0]:7.3f} {min(ts):7.3f} {statistics.median(ts):7.3f}  "
              f"{min(ts) - bare:+.3f} s ({min(ts) / bare:.1f}x)")


if __name__ == "__main__":
    main()
