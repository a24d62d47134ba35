"""Generate ``docs/api.md``, the Python API reference, from the docstrings of ``rooftrace.__all__``.

Run it after changing a public signature or docstring (a test fails while
the page is stale)::

    .venv/bin/python docs/make_api.py          # rewrite docs/api.md
    .venv/bin/python docs/make_api.py --check  # exit 1 when docs/api.md is stale
"""

from __future__ import annotations

import argparse
import inspect
import re
import sys
from pathlib import Path

PAGE = Path(__file__).resolve().parent / "api.md"

INTRO = """\
# Python API

Everything the command line does is one call into the library; these are the
entry points, importable from the top level (`import rooftrace`).  Options are
frozen dataclasses, one per stage (the same ones the `--config` TOML tables
fill).  This page is generated from the docstrings by `docs/make_api.py`; do
not edit it by hand.

```python
import rooftrace

cloud = rooftrace.read_points(["a.laz", "b.laz"], "EPSG:28992")
result = rooftrace.run_pipeline(cloud)
rooftrace.write_layers("roofs.gpkg", result.layers, cloud.crs)
```
"""

_SECTION = re.compile(r"^([A-Z][A-Za-z ]+)\n-{3,}$", re.M)


def _markdown(doc: str) -> str:
    """A numpydoc docstring as Markdown: section titles as headings, parameters as a list, examples fenced."""
    out: list[str] = []
    section = ""
    in_code = False
    lines = doc.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        if line.strip() and set(nxt.strip()) == {"-"} and len(nxt.strip()) >= 3 and not line.startswith(" "):
            if in_code:
                out.append("```")
                in_code = False
            section = line.strip()
            out += ["", f"**{section}**", ""]
            i += 2
            continue
        if section == "Examples":
            if line.startswith((">>>", "...")) or (in_code and line.strip()):
                if not in_code:
                    out.append("```python")
                    in_code = True
                out.append(line)
            else:
                if in_code:
                    out.append("```")
                    in_code = False
                out.append(line)
        elif section in ("Parameters", "Returns", "Attributes", "Raises", "Yields", "Other Parameters"):
            if line and not line.startswith(" "):
                name, _, kind = line.partition(" : ")
                out.append(f"- `{name.strip()}`" + (f" : {kind.strip()}" if kind else ""))
            elif line.strip():
                out.append("  " + line.strip())
            else:
                out.append("")
        else:
            out.append(line)
        i += 1
    if in_code:
        out.append("```")
    return re.sub(r"\n{3,}", "\n\n", "\n".join(out)).strip() + "\n"


def _signature(name: str, obj) -> str:
    try:
        sig = str(inspect.signature(obj))
    except (TypeError, ValueError):
        sig = ""
    kind = "class " if inspect.isclass(obj) else ""
    return f"{kind}rooftrace.{name}{sig}"


def render() -> str:
    """The whole page, from the installed (or ``src``) package."""
    import rooftrace

    parts = [INTRO]
    names = [n for n in rooftrace.__all__ if not n.startswith("_")]
    parts.append("| name | what |\n|---|---|\n" + "\n".join(
        f"| [`{n}`](#{n.lower()}) | {(inspect.getdoc(getattr(rooftrace, n)) or '').splitlines()[0]} |" for n in names))
    for name in names:
        obj = getattr(rooftrace, name)
        parts.append(f"## {name}\n\n```python\n{_signature(name, obj)}\n```\n\n"
                     f"Defined in `{obj.__module__}`.\n\n{_markdown(inspect.getdoc(obj) or '')}")
    return "\n\n".join(p.strip() for p in parts) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only check that docs/api.md is current")
    args = parser.parse_args(argv)
    text = render()
    if args.check:
        current = PAGE.read_text(encoding="utf-8") if PAGE.exists() else ""
        if current != text:
            print(f"{PAGE} is stale: run python docs/make_api.py", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(text, encoding="utf-8")
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
