"""The bring-up tools refuse bad paths when their arguments are parsed, naming the flag (exit 2)."""
from __future__ import annotations

import pytest

from soil_bringup import cut_report, launch


def test_a_tool_refuses_a_file_as_its_output_directory_before_it_runs(tmp_path, capsys):
    """soil_cut_report runs ~15 s of closed-loop cuts before writing: the refusal comes first."""
    (tmp_path / "taken").write_text("x")
    with pytest.raises(SystemExit) as exit_:
        cut_report.parse_args(["--out", str(tmp_path / "taken")])
    assert exit_.value.code == 2
    assert "argument --out" in capsys.readouterr().err


def test_soil_launch_refuses_a_params_file_that_does_not_exist(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        launch.parse_args(["--controller-params-file", str(tmp_path / "nosuch.yaml")])
    assert exit_.value.code == 2
    assert f"--controller-params-file {tmp_path / 'nosuch.yaml'}: no such file" in capsys.readouterr().err
