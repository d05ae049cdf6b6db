"""Output paths refused when the arguments are parsed, not after the work (no ROS)."""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from soil_msgs_py.cli_paths import bags_dir, input_path, input_text, output_dir, output_file

BIN = Path(sys.executable).parent


def test_an_output_directory_may_exist_or_not_but_is_no_file(tmp_path):
    (tmp_path / "report.md").write_text("x")
    assert output_dir(str(tmp_path)) == tmp_path
    assert output_dir(str(tmp_path / "new" / "deeper")) == tmp_path / "new" / "deeper"
    with pytest.raises(argparse.ArgumentTypeError, match="report.md' exists and is not a directory"):
        output_dir(str(tmp_path / "report.md"))
    with pytest.raises(argparse.ArgumentTypeError, match="a parent of it is a file"):
        output_dir(str(tmp_path / "report.md" / "sub"))


def test_bags_are_not_written_into_a_bag(tmp_path, capsys):
    """--record given an existing bag: the recorder wrote the new bag inside it, where every reader
    (which takes a bag directory as one bag) missed it without a word."""
    bag = tmp_path / "bags" / "default_clay_id030_v0.50_d0.100_s10"
    bag.mkdir(parents=True)
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    assert bags_dir(str(tmp_path / "bags")) == tmp_path / "bags"
    for out, says in ((bag, "is a bag"), (bag / "more", "is inside")):
        with pytest.raises(argparse.ArgumentTypeError, match=says):
            bags_dir(str(out))
    from soil_sim_node import batch

    with pytest.raises(SystemExit) as exit_:
        batch.parse_args(["--out", str(bag)])
    assert exit_.value.code == 2 and "holds metadata.yaml" in capsys.readouterr().err


def test_an_output_file_may_exist_or_not_but_is_no_directory(tmp_path):
    (tmp_path / "model.pt").write_text("x")
    assert output_file(str(tmp_path / "model.pt")) == tmp_path / "model.pt"
    assert output_file(str(tmp_path / "new.pt")) == tmp_path / "new.pt"
    with pytest.raises(argparse.ArgumentTypeError, match="is a directory; give the file to write"):
        output_file(str(tmp_path))


def test_an_empty_output_path_is_refused(tmp_path, capsys):
    """``--out ""`` (say an unset shell variable) meant the current directory for a directory output."""
    for kind in (output_dir, output_file):
        with pytest.raises(argparse.ArgumentTypeError, match="'' is empty; give a path"):
            kind("")
    p = argparse.ArgumentParser(prog="tool")
    p.add_argument("--out", type=output_dir)
    with pytest.raises(SystemExit) as exit_:
        p.parse_args(["--out", ""])
    assert exit_.value.code == 2
    assert "argument --out: '' is empty" in capsys.readouterr().err


@pytest.mark.parametrize("tool, args", [
    ("soil_sim_batch", ["--mode", "fee", "--soils", "Sand", "--relative-densities", "20", "--speeds", "0.5",
                        "--depths", "0.1", "--seeds", "1", "--duration", "0.5", "--workers", "1", "--quiet"]),
    ("soil_cut_report", ["--worlds", "fee", "--duration", "1"]),
])
def test_the_tools_refuse_an_empty_out_and_write_nothing(tmp_path, tool, args):
    """Once an empty --out wrote the bags or the report into the current directory."""
    out = subprocess.run([str(BIN / tool), "--out", "", *args], cwd=tmp_path, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 2, out.stdout + out.stderr
    assert "argument --out: '' is empty" in out.stderr and "Traceback" not in out.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("tool, args", [
    ("soil_bag_play", [""]), ("soil_bag_repair", [""]), ("soil_plot_episode", [""]), ("soil_discrepancy", [""]),
    ("pinn_train", ["--data", "", "--out", "m.pt"]), ("pinn_eval", ["--checkpoint", ""]),
])
def test_the_tools_refuse_an_empty_path_to_read(tmp_path, tool, args):
    """An empty path (an unset shell variable: ``soil_bag_play "$BAG"``) was the current
    directory: every bag under it replayed into the live graph, repaired or trained on."""
    assert input_text("bags") == "bags" and input_path("bags") == Path("bags")
    out = subprocess.run([str(BIN / tool), *args], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stdout + out.stderr
    assert "'' is empty; give a path" in out.stderr and "Traceback" not in out.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_place_nothing_can_be_written_is_refused_and_the_probe_leaves_nothing(tmp_path):
    """An --out that cannot be written (here /proc, where no file can be made, root or not; a
    read-only mount alike) failed only when the tool wrote, after minutes of work, with a
    traceback. The check creates nothing: a new --out's directories are left to the tool."""
    for kind, text in ((output_dir, "/proc/insitu_soil_eval"), (output_file, "/proc/insitu_soil.pt")):
        with pytest.raises(argparse.ArgumentTypeError, match="cannot be written: nothing can be created in '/proc'"):
            kind(text)
    assert output_dir(str(tmp_path / "a" / "b")) == tmp_path / "a" / "b"
    assert output_file(str(tmp_path / "c" / "model.pt")) == tmp_path / "c" / "model.pt"
    assert list(tmp_path.iterdir()) == []


def test_a_directory_where_a_tool_writes_a_file_is_refused_before_the_work(tmp_path, capsys):
    """An outside tester's: a directory named like a file a tool writes (m_curve.png beside a
    checkpoint, discrepancy.json, dataset.json, ...) cost the whole run, an IsADirectoryError at the
    end and a temporary file left behind. Each tool now refuses it first, naming it, exit 2."""
    from pinn_estimator.evaluate import main as eval_main
    from pinn_estimator.train import main as train_main
    from soil_bringup.cut_report import main as cut_main
    from soil_discrepancy.cli import main as discrepancy_main
    from soil_sim_node.batch import main as batch_main
    from soil_sim_node.plot import main as plot_main

    bag = tmp_path / "bag"
    bag.mkdir()
    cases = [
        (batch_main, ["--out", str(tmp_path / "sb"), "--soils", "Clay", "--relative-densities", "40", "--speeds", "0.5",
                      "--depths", "0.1", "--seeds", "1", "--duration", "2", "--quiet"], tmp_path / "sb" / "dataset.json"),
        (train_main, ["--data", str(bag), "--out", str(tmp_path / "m.pt"), "--quiet"], tmp_path / "m_curve.png"),
        (eval_main, ["--checkpoint", str(tmp_path / "m.pt"), "--out", str(tmp_path / "ev"), "--name", "r", "--quiet"],
         tmp_path / "ev" / "r.md"),
        (cut_main, ["--worlds", "fee", "--out", str(tmp_path / "cr")], tmp_path / "cr" / "cut_fee.png"),
        (discrepancy_main, [str(bag), "--out", str(tmp_path / "dj"), "--quiet"], tmp_path / "dj" / "discrepancy.json"),
        (discrepancy_main, [str(bag), "--out", str(tmp_path / "dk"), "--quiet"], tmp_path / "dk" / "candidates.png"),
        (plot_main, [str(bag)], tmp_path / "bag.png"),
    ]
    for main, argv, squatter in cases:
        squatter.mkdir(parents=True)
        assert main(argv) == 2, squatter
        err = capsys.readouterr().err
        assert f"{str(squatter)!r} is a directory where this run writes a file" in err, err
        assert not list((tmp_path / "sb").glob("dataset.json.*")) and not list(squatter.parent.glob("*.tmp"))


def test_a_file_replaced_atomically_is_whole_or_untouched(tmp_path):
    """A report, checkpoint or config written in place and interrupted was left truncated
    (``pinn_fusion_calibrate`` writes the shipped config by default): written beside and renamed."""
    from soil_msgs_py.cli_paths import replace_atomically

    path = tmp_path / "config.json"
    path.write_text("old")
    replace_atomically(path, lambda tmp: tmp.write_text("new"))
    assert path.read_text() == "new" and [p.name for p in tmp_path.iterdir()] == ["config.json"]

    def interrupted(tmp):
        tmp.write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        replace_atomically(path, interrupted)
    assert path.read_text() == "new" and [p.name for p in tmp_path.iterdir()] == ["config.json"]
    assert replace_atomically(tmp_path / "fig.png", lambda tmp: tmp.write_bytes(b"png") if tmp.suffix == ".png" else None,
                              suffix=".tmp.png").read_bytes() == b"png"


def test_a_figure_is_saved_whole_in_its_suffixs_format_or_the_old_one_stays(tmp_path):
    """Figures (calibration curves, reports' plots) were written in place: an interrupted save left
    a truncated image. The format is the path's suffix's, not the temporary sibling's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from soil_msgs_py.cli_paths import save_figure_atomically

    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    png, pdf = save_figure_atomically(fig, tmp_path / "a.png", dpi=50), save_figure_atomically(fig, tmp_path / "b.pdf", dpi=50)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and pdf.read_bytes()[:5] == b"%PDF-"

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    fig.savefig = interrupted
    with pytest.raises(KeyboardInterrupt):
        save_figure_atomically(fig, png, dpi=50)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "b.pdf"]
    plt.close(fig)
