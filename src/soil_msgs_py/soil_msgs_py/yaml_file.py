"""Reading a user's YAML file (soils, a catalogue of terms, soil tests) with errors that name the file."""
from __future__ import annotations

from pathlib import Path


class DuplicateKey(ValueError):
    """A mapping of a user's YAML file gives one key twice."""


def _unique_key_loader():
    """PyYAML's safe loader, refusing a key given twice in one mapping: it keeps the last value in
    silence, so a params file giving ``duration_s`` twice ran the episode the second one said
    (an outside tester's), and the user cannot tell which value they meant."""
    import yaml

    class UniqueKeyLoader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            if isinstance(node, yaml.MappingNode):
                seen: dict = {}
                for key_node, _ in node.value:
                    if key_node.tag == "tag:yaml.org,2002:merge":  # (``<<:``: its keys are the merged map's)
                        continue
                    key = self.construct_object(key_node, deep=True)
                    line = key_node.start_mark.line + 1
                    try:
                        first = seen.get(key)
                    except TypeError:  # an unhashable key: PyYAML says so itself
                        continue
                    if first is not None:
                        raise DuplicateKey(f"key {key!r} appears twice in one mapping (lines {first} and {line}): "
                                           "which value is meant? Give it once")
                    seen[key] = line
            return super().construct_mapping(node, deep=deep)

    return UniqueKeyLoader


def read_yaml(path, what: str):
    """The YAML content of ``path``; ValueError "<what> <path> ..." for a file that is missing,
    unreadable, not UTF-8 (a binary file: the codec's words alone do not say which), not YAML, or
    giving one key twice in a mapping (``DuplicateKey``)."""
    import yaml

    p = Path(path)
    try:
        return yaml.load(p.read_text(encoding="utf-8"), Loader=_unique_key_loader())  # noqa: S506 - a safe loader
    except DuplicateKey as exc:
        raise DuplicateKey(f"{what} {p}: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{what} {p} is not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except yaml.YAMLError as exc:  # one line: the parser's problem and where (its own text is 8 lines)
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ValueError(f"{what} {p} is not YAML: {problem}{where}") from None
    except OSError as exc:
        raise ValueError(f"{what} {p}: cannot read it: {exc}") from None
