"""Output paths refused when the arguments are parsed, not after the work (no ROS)."""
from __future__ import annotations

import argparse

import pytest

from soil_msgs_py.cli_paths import output_dir, output_file


def test_an_output_directory_may_exist_or_not_but_is_no_file(tmp_path):
    (tmp_path / "report.md").write_text("x")
    assert output_dir(str(tmp_path)) == tmp_path
    assert output_dir(str(tmp_path / "new" / "deeper")) == tmp_path / "new" / "deeper"
    with pytest.raises(argparse.ArgumentTypeError, match="report.md' exists and is not a directory"):
        output_dir(str(tmp_path / "report.md"))
    with pytest.raises(argparse.ArgumentTypeError, match="a parent of it is a file"):
        output_dir(str(tmp_path / "report.md" / "sub"))


def test_an_output_file_may_exist_or_not_but_is_no_directory(tmp_path):
    (tmp_path / "model.pt").write_text("x")
    assert output_file(str(tmp_path / "model.pt")) == tmp_path / "model.pt"
    assert output_file(str(tmp_path / "new.pt")) == tmp_path / "new.pt"
    with pytest.raises(argparse.ArgumentTypeError, match="is a directory; give the file to write"):
        output_file(str(tmp_path))
