"""Coverage-guided fuzzing of the native FMUs with libFuzzer (docs/fuzzing.md).

    python tests/fuzz/fuzz.py [--seconds 30] [--model FlexiblePendulum] [--keep DIR]

builds one libFuzzer target per model (``tests/fuzz/fuzz_fmi.c`` linked with the model, the
instance core and both FMI adapters, under ``-fsanitize=fuzzer,address,undefined``), replays the
committed corpus (``tests/fuzz/corpus/<model>/``: every past finding is a regression input), then
fuzzes each target for ``--seconds`` and prints, per target, the executions per second, the
edges covered (of the instrumented ones) and any finding. It exits with 1 on a finding (a crash,
a sanitizer report, a broken contract of the harness, a timeout or a leak): the input is left in
the working folder (``--keep``) and named in the output. New inputs go to a temporary copy of the
corpus; ``--merge`` adds the ones that add coverage to the committed corpus.

The compiler is clang 14 (Debian's ``clang-14``; ``clang`` also works). The build uses a substep
cap of 1000 per doStep instead of the product's 1 000 000 (the same code: a step above the cap is
refused either way), so that an input that asks for the cap costs milliseconds.
"""
from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
CORPUS = HERE / "corpus"
MODELS = ("FlexiblePendulum", "PDLowPass")
FUZZ_TOKEN = "{f0220000-0000-4000-8000-000000000023}"
FUZZ_MAX_SUBSTEPS = 1000
FUZZ_MAX_EXACT_WORK = 20000     # element-iterations (plant_model.c: FPM_MAX_EXACT_WORK)
FLAGS = ["-g", "-O1", "-std=c99", "-Wall", "-Wextra", "-Werror", "-ffp-contract=off",
         "-fsanitize=fuzzer,address,undefined,float-divide-by-zero", "-fno-sanitize-recover=all",
         "-fno-omit-frame-pointer"]
#: libFuzzer's options for every run: a second per input is far above what any input needs
RUN_OPTIONS = ["-timeout=10", "-rss_limit_mb=2048", "-max_len=4096", "-print_final_stats=1"]


class FuzzError(RuntimeError):
    """The fuzzer could not be built or run (not a finding)."""


def find_clang() -> str | None:
    """clang-14 or clang, if installed."""
    return shutil.which("clang-14") or shutil.which("clang")


def build(model: str, out_dir: Path, cc: str | None = None, flags=None, suffix="") -> Path:
    """The libFuzzer target of ``model`` in ``out_dir`` (``flags``: instead of :data:`FLAGS`)."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from fmu_common import kernels
    from orchestration.export import native_fmus

    cc = cc or find_clang()
    if cc is None:
        raise FuzzError("no clang (apt-get install clang-14)")
    out_dir.mkdir(parents=True, exist_ok=True)
    gen = out_dir / f"gen_{model}"
    gen.mkdir(exist_ok=True)
    (gen / "fpm_vars.h").write_text(native_fmus.generate_header(model, FUZZ_TOKEN))
    src = native_fmus.SRC
    sources = [HERE / "fuzz_fmi.c", src / "fmi2.c", src / "fmi3.c",
               *(src / f for f in native_fmus.CORE_SOURCES), native_fmus.model_source(model)]
    includes = [gen, src, native_fmus.fmi_include_dir()]
    for k in native_fmus.MODELS[model][1]:
        native = kernels.native_dir(k)
        sources += [native / s for s in kernels.KERNELS[k][1]]
        includes.append(native)
    exe = out_dir / f"fuzz_{model}{suffix}"
    cmd = [cc, *(FLAGS if flags is None else flags), "-DFP_API=", "-DFPF_API=", f"-DFPM_MAX_SUBSTEPS={FUZZ_MAX_SUBSTEPS}L",
           f"-DFPM_MAX_EXACT_WORK={FUZZ_MAX_EXACT_WORK}L", *(f"-I{d}" for d in includes), "-o", str(exe), *map(str, sources), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise FuzzError(f"building the fuzzer of {model} failed:\n{' '.join(cmd)}\n"
                        f"{proc.stdout}{proc.stderr}")
    return exe


def _stats(text: str) -> dict:
    out = {}
    for key in ("number_of_executed_units", "average_exec_per_sec", "peak_rss_mb"):
        m = re.search(rf"stat::{key}:\s+(\d+)", text)
        if m:
            out[key] = int(m.group(1))
    done = re.findall(r"#(\d+)\s+(?:DONE|INITED)\s+cov: (\d+) ft: (\d+)", text)
    if done:
        out["cov"], out["ft"] = int(done[-1][1]), int(done[-1][2])
    m = re.search(r"Loaded \d+ modules\s+\((\d+) inline 8-bit counters\)", text)
    if m:
        out["edges"] = int(m.group(1))
    return out


def replay(exe: Path, corpus: Path, workdir: Path) -> dict:
    """Run every input of ``corpus`` once; ``{"ok": bool, "output": text, ...stats}``."""
    files = sorted(p for p in corpus.iterdir() if p.is_file()) if corpus.is_dir() else []
    if not files:
        return {"ok": True, "output": "", "inputs": 0}
    proc = subprocess.run([str(exe), *RUN_OPTIONS, f"-artifact_prefix={workdir}/",
                           *map(str, files)], capture_output=True, text=True, timeout=1800)
    return {"ok": proc.returncode == 0, "output": proc.stderr[-6000:], "inputs": len(files),
            **_stats(proc.stderr)}


def fuzz(exe: Path, corpus: Path, seconds: int, workdir: Path) -> dict:
    """Fuzz for ``seconds`` from a copy of ``corpus``; ``{"ok", "output", "findings", stats}``."""
    scratch = workdir / f"corpus_{exe.name}"
    shutil.rmtree(scratch, ignore_errors=True)
    scratch.mkdir(parents=True)
    if corpus.is_dir():
        for p in corpus.iterdir():
            if p.is_file():
                shutil.copy(p, scratch / p.name)
    artifacts = workdir / f"findings_{exe.name}"     # this target's own: not another's
    artifacts.mkdir(exist_ok=True)
    proc = subprocess.run([str(exe), *RUN_OPTIONS, f"-max_total_time={seconds}",
                           f"-artifact_prefix={artifacts}/", str(scratch)],
                          capture_output=True, text=True, timeout=seconds + 600)
    findings = sorted(str(p) for p in artifacts.iterdir()
                      if p.name.startswith(("crash-", "leak-", "timeout-", "oom-")))
    return {"ok": proc.returncode == 0 and not findings, "output": proc.stderr[-6000:],
            "findings": findings, "scratch": scratch, **_stats(proc.stderr)}


def line_coverage(model: str, corpora, work: Path) -> str:
    """llvm-cov's report of the lines of the core, the adapters and the model that the inputs of
    ``corpora`` (folders) execute, from a build with source-based coverage (no sanitizers)."""
    cov = shutil.which("llvm-cov-14") or shutil.which("llvm-cov")
    prof = shutil.which("llvm-profdata-14") or shutil.which("llvm-profdata")
    if cov is None or prof is None:
        return "(no llvm-cov / llvm-profdata)"
    flags = ["-g", "-O1", "-std=c99", "-ffp-contract=off", "-fsanitize=fuzzer",
             "-fprofile-instr-generate", "-fcoverage-mapping"]
    exe = build(model, work, flags=flags, suffix="_cov")
    raw = work / f"{model}.profraw"
    files = [str(p) for d in corpora if Path(d).is_dir() for p in Path(d).iterdir() if p.is_file()]
    subprocess.run([str(exe), *RUN_OPTIONS, *files], capture_output=True, text=True,
                   env={"LLVM_PROFILE_FILE": str(raw), "PATH": "/usr/bin:/bin"}, timeout=3600)
    data = work / f"{model}.profdata"
    subprocess.run([prof, "merge", "-sparse", str(raw), "-o", str(data)], check=True,
                   capture_output=True)
    from orchestration.export import native_fmus
    src = native_fmus.SRC
    sources = [src / "fpm_guard.c", src / "fpm_core.c", src / "fmi2.c", src / "fmi3.c",
               native_fmus.model_source(model)]
    out = subprocess.run([cov, "report", str(exe), f"-instr-profile={data}",
                          *map(str, sources)], capture_output=True, text=True, check=True)
    return out.stdout


def merge(exe: Path, corpus: Path, scratch: Path) -> None:
    """Add to ``corpus`` the inputs of ``scratch`` that add coverage."""
    corpus.mkdir(parents=True, exist_ok=True)
    subprocess.run([str(exe), "-merge=1", *RUN_OPTIONS, str(corpus), str(scratch)],
                   capture_output=True, text=True, check=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=int, default=30, help="fuzzing time per target")
    ap.add_argument("--model", action="append", choices=MODELS,
                    help="a model to fuzz (default: both)")
    ap.add_argument("--keep", help="working folder (default: a temporary one, removed)")
    ap.add_argument("--merge", action="store_true",
                    help="add the new inputs that add coverage to the committed corpus")
    ap.add_argument("--lines", action="store_true",
                    help="report the lines covered by the corpus and the run's inputs (llvm-cov)")
    args = ap.parse_args(argv)
    if args.seconds < 1:
        print(f"fuzz.py: --seconds = {args.seconds}; allowed: >= 1", file=sys.stderr)
        return 2
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="flexpend_fuzz_"))
    work.mkdir(parents=True, exist_ok=True)
    failed = False
    try:
        for model in args.model or MODELS:
            exe = build(model, work)
            r = replay(exe, CORPUS / model, work)
            print(f"{model}: replayed {r['inputs']} corpus inputs: "
                  f"{'ok' if r['ok'] else 'FINDING'}")
            if not r["ok"]:
                print(r["output"])
                failed = True
                continue
            f = fuzz(exe, CORPUS / model, args.seconds, work)
            print(f"{model}: {f.get('number_of_executed_units', 0)} executions in {args.seconds} s"
                  f" ({f.get('average_exec_per_sec', 0)} exec/s), cov {f.get('cov', 0)} of "
                  f"{f.get('edges', 0)} edges, ft {f.get('ft', 0)}: "
                  f"{'ok' if f['ok'] else 'FINDING ' + ' '.join(f['findings'])}")
            if not f["ok"]:
                print(f["output"])
                failed = True
            elif args.merge:
                merge(exe, CORPUS / model, f["scratch"])
            if args.lines:
                print(line_coverage(model, [CORPUS / model, f["scratch"]], work))
    finally:
        if not args.keep and not failed:
            shutil.rmtree(work, ignore_errors=True)
        elif failed:
            print(f"inputs and logs kept in {work}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
