"""A user's YAML file (``soil_msgs_py.yaml_file.read_yaml``): a key given twice in one mapping is
refused naming it and both lines; merges and anchors, which override keys on purpose, are not."""
from __future__ import annotations

import pytest

from soil_msgs_py.yaml_file import DuplicateKey, read_yaml


@pytest.mark.parametrize("text, said", [
    ("a: 1\nb:\n  c: 2\n  c: 3\n", "key 'c' appears twice in one mapping (lines 3 and 4)"),
    ("a: {k: 1, k: 2}\n", "key 'k' appears twice in one mapping (lines 1 and 1)"),
    ("l:\n  - {x: 1, y: 2}\n  - {x: 1, x: 3}\n", "key 'x' appears twice in one mapping (lines 3 and 3)"),
    ("1: a\n1.0: b\n", "key 1.0 appears twice in one mapping (lines 1 and 2)"),  # one key to any reader
])
def test_a_key_given_twice_is_refused_naming_it_and_its_lines(tmp_path, text, said):
    path = tmp_path / "f.yaml"
    path.write_text(text)
    with pytest.raises(DuplicateKey) as err:
        read_yaml(path, "params file")
    assert str(err.value).startswith(f"params file {path}: {said}"), err.value


def test_merges_and_anchors_override_keys_on_purpose_and_load_as_pyyaml_loads_them(tmp_path):
    path = tmp_path / "f.yaml"
    path.write_text("base: &b {x: 1, y: 2}\nover:\n  <<: *b\n  x: 3\n"
                    "o: &o {x: 1}\nfirst: {<<: &c {<<: *o, x: 2}}\nsecond: *c\n")
    assert read_yaml(path, "f") == {"base": {"x": 1, "y": 2}, "over": {"x": 3, "y": 2}, "o": {"x": 1},
                                    "first": {"x": 2}, "second": {"x": 2}}
    path.write_text("a: [1, 2\n")  # (what the parser refuses is its to say)
    with pytest.raises(ValueError, match="is not YAML"):
        read_yaml(path, "f")
