"""Reading a user's YAML file (soils, a catalogue of terms, soil tests) with errors that name the file."""
from __future__ import annotations

from pathlib import Path


def read_yaml(path, what: str):
    """The YAML content of ``path``; ValueError "<what> <path> ..." for a file that is missing,
    unreadable, not UTF-8 (a binary file: the codec's words alone do not say which) or not YAML."""
    import yaml

    p = Path(path)
    try:
        return yaml.safe_load(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise ValueError(f"{what} {p} is not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except yaml.YAMLError as exc:  # one line: the parser's problem and where (its own text is 8 lines)
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ValueError(f"{what} {p} is not YAML: {problem}{where}") from None
    except OSError as exc:
        raise ValueError(f"{what} {p}: cannot read it: {exc}") from None
