"""Sphinx directives of goniofrost's docs: tables generated from the code and from committed JSON.

- ``keytables MODULE``: every key table (a mapping of ``goniofrost.core.config_check.Key``) defined
  at the top of MODULE, one table each (key, what a good value is, default), so the reference of
  the rig-file and queue-file keys cannot drift from the checks. The directive's content may give
  a caption per table, one ``NAME: caption`` a line; a table without one is still listed.
- ``json-table PATH``: a table from a JSON file (relative to the page): ``:key:`` a dotted path to a
  list of rows (mappings, or lists under a ``columns`` list beside them), ``:columns:`` which keys
  to show, in order (default: every key of the first row).
- ``sqlite-schema MODULE.NAME``: one table per SQLite table of the schema string MODULE.NAME (the
  journal's), its columns, types and constraints read back from SQLite itself.
- Docstrings are written as plain text with ````code```` spans; one that is not valid reStructuredText
  (a hanging indent, a ``|`` pair) is shown as it is written, as a literal block, so that autodoc
  builds without warnings whatever the docstring's layout.
- ``benchmark-results PATH``: a benchmark's committed results (``docs/benchmarks/results/NAME.json``):
  its command, machine, load and date, then each of its ``tables`` (title, columns, rows).
"""
from __future__ import annotations

import importlib
import json
from collections.abc import Mapping
from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import directives
from sphinx.util.docutils import SphinxDirective


def key_tables(module) -> list[tuple[str, Mapping]]:
    """(name, table) of every key table at the top of ``module``, in definition order; an alias of a
    table already listed (``TOP_KEYS = _TOP_KEYS``) is left out."""
    from goniofrost.core.config_check import Key

    found, seen = [], set()
    for name, value in vars(module).items():
        if (isinstance(value, Mapping) and value and all(isinstance(v, Key) for v in value.values())
                and id(value) not in seen):
            seen.add(id(value))
            found.append((name, value))
    return found


def default_text(key) -> str:
    """A Key's default in words: required, may be left out, or the value used."""
    from goniofrost.core.config_check import ABSENT, REQUIRED

    if key.default is REQUIRED:
        return "required"
    if key.default is ABSENT:
        return "optional (left out)"
    return json.dumps(key.default) if isinstance(key.default, (int, float, str, bool, type(None), list, dict)) \
        else repr(key.default)


def table(header: list[str], rows: list[list[str]], literal_first: bool = True) -> nodes.table:
    """A docutils table of text cells (the first column as code when ``literal_first``)."""
    tgroup = nodes.tgroup(cols=len(header))
    tgroup += [nodes.colspec(colwidth=1) for _ in header]
    def row(cells, head=False):
        tr = nodes.row()
        for i, cell in enumerate(cells):
            text = str(cell)
            para = nodes.paragraph()
            para += nodes.literal(text, text) if (literal_first and i == 0 and not head) else nodes.Text(text)
            tr += nodes.entry("", para)
        return tr
    thead = nodes.thead()
    thead += row(header, head=True)
    tbody = nodes.tbody()
    tbody += [row(cells) for cells in rows]
    tgroup += [thead, tbody]
    out = nodes.table()
    out += tgroup
    return out


class KeyTables(SphinxDirective):
    required_arguments = 1
    has_content = True

    def run(self):
        module = importlib.import_module(self.arguments[0])
        self.env.note_dependency(module.__file__)
        captions = dict(line.split(":", 1) for line in self.content if ":" in line)
        out = []
        for name, keys in key_tables(module):
            title = f"{captions.get(name, '').strip() or name} ({self.arguments[0]}.{name})"
            out.append(nodes.rubric(title, title))
            out.append(table(["key", "expected", "default"],
                             [[key, spec.expected, default_text(spec)] for key, spec in keys.items()]))
        return out


def _lookup(data, dotted: str):
    for part in filter(None, dotted.split(".")):
        data = data[int(part)] if isinstance(data, list) else data[part]
    return data


def _cell(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return "" if value is None else str(value)


def rows_of(data, columns: list[str] | None) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of a JSON table: a mapping with ``columns`` and ``rows`` (lists), or a list of
    mappings (header: ``columns``, else the first row's keys)."""
    if isinstance(data, Mapping):
        header = list(data["columns"])
        picked = [header.index(c) for c in columns] if columns else range(len(header))
        return [header[i] for i in picked], [[_cell(row[i]) for i in picked] for row in data["rows"]]
    header = columns or list(data[0])
    return header, [[_cell(row.get(c)) for c in header] for row in data]


class JsonTable(SphinxDirective):
    required_arguments = 1
    option_spec = {"key": directives.unchanged, "columns": directives.unchanged}

    def run(self):
        rel, path = self.env.relfn2path(self.arguments[0])
        self.env.note_dependency(rel)
        data = _lookup(json.loads(Path(path).read_text()), self.options.get("key", ""))
        columns = [c.strip() for c in self.options["columns"].split(",")] if "columns" in self.options else None
        header, rows = rows_of(data, columns)
        return [table(header, rows, literal_first=False)]


class BenchmarkResults(SphinxDirective):
    required_arguments = 1

    def run(self):
        rel, path = self.env.relfn2path(self.arguments[0])
        self.env.note_dependency(rel)
        data = json.loads(Path(path).read_text())
        out = []
        facts = nodes.bullet_list()
        for label in ("command", "machine", "load", "date", "code"):
            if data.get(label):
                item = nodes.list_item()
                para = nodes.paragraph()
                para += nodes.strong(label, label)
                para += nodes.Text(": ")
                text = str(data[label])
                para += nodes.literal(text, text) if label == "command" else nodes.Text(text)
                item += para
                facts += item
        out.append(facts)
        for part in data.get("tables", []):
            if part.get("title"):
                out.append(nodes.rubric(part["title"], part["title"]))
            header, rows = rows_of(part, None)
            out.append(table(header, rows, literal_first=False))
            if part.get("note"):
                out.append(nodes.paragraph(part["note"], part["note"]))
        return out


class SqliteSchema(SphinxDirective):
    required_arguments = 1

    def run(self):
        import sqlite3

        module_name, _, name = self.arguments[0].rpartition(".")
        module = importlib.import_module(module_name)
        self.env.note_dependency(module.__file__)
        db = sqlite3.connect(":memory:")
        db.executescript(getattr(module, name))
        out = []
        for (table_name,) in db.execute("SELECT name FROM sqlite_master WHERE type = 'table' "
                                        "AND name NOT LIKE 'sqlite_%' ORDER BY rowid"):
            out.append(nodes.rubric(table_name, table_name))
            rows = [[col, kind, " ".join(filter(None, ["primary key" if pk else "", "not null" if notnull else "",
                                                       f"default {default}" if default is not None else ""]))]
                    for _, col, kind, notnull, default, pk in db.execute(f"PRAGMA table_info({table_name})")]
            out.append(table(["column", "type", "constraints"], rows))
        db.close()
        return out


def _is_clean_rest(text: str) -> bool:
    """Whether docutils parses ``text`` without a warning (Sphinx's roles and directives aside)."""
    from docutils.core import publish_doctree

    try:
        tree = publish_doctree(text, settings_overrides={"report_level": 5, "halt_level": 5,
                                                         "warning_stream": False})
    except Exception:
        return False
    messages = [*tree.findall(nodes.system_message), *tree.transform_messages]
    return not any(msg["level"] >= 2 for msg in messages) and not any(tree.findall(nodes.problematic))


def plain_docstrings(app, what, name, obj, options, lines) -> None:
    """autodoc-process-docstring: a docstring that is not clean reST becomes a literal block."""
    text = "\n".join(lines)
    if not text.strip() or _is_clean_rest(text):
        return
    lines[:] = ["::", ""] + ["    " + line if line else "" for line in lines]


def setup(app):
    app.connect("autodoc-process-docstring", plain_docstrings)
    app.add_directive("keytables", KeyTables)
    app.add_directive("json-table", JsonTable)
    app.add_directive("benchmark-results", BenchmarkResults)
    app.add_directive("sqlite-schema", SqliteSchema)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
