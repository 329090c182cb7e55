"""``flexpend run --figures none`` and ``Run.save(figures="none")``: no figure drawn or written,
everything else the same as with the figures."""
import json
import re
from pathlib import Path

import pytest

from orchestration import simulate
from orchestration.cli import main
from orchestration.report import figures as figures_module


def _timeless(data):
    """``data`` (a summary) without its wall times, which differ from run to run."""
    if isinstance(data, dict):
        return {k: _timeless(v) for k, v in data.items() if k != "wall_time"}
    if isinstance(data, list):
        return [_timeless(v) for v in data]
    return data


def _run(capsys, out: Path, *extra) -> tuple[int, str]:
    code = main(["run", "rigid_pd", "flexible_pd", "--set", "stop_time=0.5", "--out", str(out),
                 *extra])
    return code, capsys.readouterr().out


def test_figures_none_writes_the_same_files_but_the_pngs_and_prints_the_same(
        tmp_path, capsys, monkeypatch, fmus):
    code_png, text_png = _run(capsys, tmp_path / "png")
    drawn = []
    for name in ("time_histories", "snapshots", "paper_overview", "mode_shapes", "root_map"):
        real = getattr(figures_module, name)
        monkeypatch.setattr(figures_module, name,
                            lambda *a, _name=name, _real=real, **k: drawn.append(_name)
                            or _real(*a, **k))
    code_none, text_none = _run(capsys, tmp_path / "none", "--figures", "none")
    assert code_png == code_none == 0
    assert drawn == []                                      # nothing rendered

    with_png = sorted(p.name for p in (tmp_path / "png").iterdir())
    without = sorted(p.name for p in (tmp_path / "none").iterdir())
    assert any(n.endswith(".png") for n in with_png)
    assert without == [n for n in with_png if not n.endswith(".png")]
    for name in without:                                    # the CSV files and the summary
        a, b = (tmp_path / "none" / name).read_bytes(), (tmp_path / "png" / name).read_bytes()
        if name.endswith(".json"):
            assert _timeless(json.loads(a)) == _timeless(json.loads(b))
        else:
            assert a == b

    # stdout: the same lines, but the "wrote" lines name the same files less the PNGs
    def _drop_pngs(line: str) -> str:
        line = re.sub(r"wall time: \S+ s", "wall time: T s", line)
        if not line.lstrip().startswith("wrote "):
            return line
        head, files = line.split("wrote ", 1)
        kept = [f for f in files.split(", ") if not f.endswith(".png")]
        return head + "wrote " + ", ".join(Path(f).name for f in kept)

    lines_png, lines_none = text_png.splitlines(), text_none.splitlines()
    assert sum("wrote " in ln and ".png" in ln for ln in lines_png) == 2
    assert not any(".png" in ln for ln in lines_none)
    assert [_drop_pngs(ln) for ln in lines_png] == [_drop_pngs(ln) for ln in lines_none]


def test_run_save_figures_none_writes_the_csv_and_summary_only(tmp_path, fmus):
    run = simulate("rigid_pd", {"stop_time": 0.2})
    written = run.save(tmp_path / "a", figures="none")
    assert sorted(p.name for p in written) == ["rigid_pd.csv", "summary.json"]
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["rigid_pd.csv", "summary.json"]
    written = run.save(tmp_path / "b")
    assert {p.name for p in written} == {"rigid_pd.csv", "rigid_pd.png", "rigid_pd_shapes.png",
                                         "summary.json"}
    assert (tmp_path / "a" / "rigid_pd.csv").read_bytes() == \
        (tmp_path / "b" / "rigid_pd.csv").read_bytes()
    assert json.loads((tmp_path / "a" / "summary.json").read_text()).keys() == {"rigid_pd"}


def test_a_bad_figures_value_is_refused_in_one_line(tmp_path, fmus):
    run = simulate("rigid_pd", {"stop_time": 0.2})
    with pytest.raises(ValueError, match=r"^figures = 'svg' is not allowed; allowed: 'png', "
                                         r"'none'$"):
        run.save(tmp_path, figures="svg")
    assert not tmp_path.joinpath("rigid_pd.csv").exists()
