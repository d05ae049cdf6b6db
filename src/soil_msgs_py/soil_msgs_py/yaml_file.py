"""Reading a user's YAML file (soils, a catalogue of terms, soil tests) with errors that name the file."""
from __future__ import annotations

from pathlib import Path


class DuplicateKey(ValueError):
    """A mapping of a user's YAML file gives one key twice."""


def check_unique_keys(text: str) -> None:
    """``DuplicateKey`` for a mapping of the YAML ``text`` that gives one key twice. PyYAML (and
    rcl) keep the last value in silence, so a params file giving ``duration_s`` twice ran the
    episode the second one said (an outside tester's), and the user cannot tell which was meant.
    Judged on the composed nodes, before any ``<<`` merge is applied (a merge's keys are the merged
    map's, overridden on purpose); YAML the parser refuses is left to it."""
    import yaml

    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return
    keys = yaml.SafeLoader("")  # (a constructor for the key scalars: 1 and 1.0, ~ and null are one key)
    seen_nodes: set[int] = set()
    stack = [root] if root is not None else []
    while stack:
        node = stack.pop()
        if id(node) in seen_nodes:  # (an alias: the anchored node, judged once)
            continue
        seen_nodes.add(id(node))
        if isinstance(node, yaml.MappingNode):
            lines: dict = {}
            for key_node, value_node in node.value:
                stack += [key_node, value_node]
                if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                    continue
                try:
                    key = keys.construct_object(key_node, deep=True)
                    first = lines.get(key)
                except (yaml.YAMLError, TypeError, ValueError):
                    continue  # (the loader says what is wrong with the key itself)
                line = key_node.start_mark.line + 1
                if first is not None:
                    raise DuplicateKey(f"key {key!r} appears twice in one mapping (lines {first} and {line}): "
                                       "which value is meant? Give it once")
                lines[key] = line
        elif isinstance(node, yaml.SequenceNode):
            stack += list(node.value)


def read_yaml(path, what: str):
    """The YAML content of ``path``; ValueError "<what> <path> ..." for a file that is missing,
    unreadable, not UTF-8 (a binary file: the codec's words alone do not say which), not YAML, or
    giving one key twice in a mapping (``DuplicateKey``)."""
    import yaml

    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
        check_unique_keys(text)
        return yaml.safe_load(text)
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
