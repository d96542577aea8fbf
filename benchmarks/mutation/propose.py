"""Propose single-line mutants of a module (candidates for ``mutants.toml``; a person picks).

``python benchmarks/mutation/propose.py models/network/links.py [-n 6] [--seed 0]`` prints TOML
``[[mutant]]`` entries: an arithmetic operator swapped (``+``/``-``, ``*``/``/``), a comparison
turned (``<``/``<=``, ``==``/``!=``, ``in``/``not in``), ``and``/``or`` swapped, a unary minus or
``not`` dropped, a number changed (``0``/``1``, ``2`` -> ``1``, ``x`` -> ``x / 2``), a ``True``/``False``
flipped. Lines in docstrings, log and exception messages and module-level constants are left
out; the snippet is the whole line, which must be unique in the file.
"""
from __future__ import annotations

import argparse
import ast
import random
import sys
from pathlib import Path
from typing import Iterator, List, Tuple

ROOT = Path(__file__).resolve().parents[2]
BIN = {ast.Add: ("+", "-"), ast.Sub: ("-", "+"), ast.Mult: ("*", "/"), ast.Div: ("/", "*"),
       ast.FloorDiv: ("//", "*"), ast.Mod: ("%", "//"), ast.Pow: ("**", "*")}
CMP = {ast.Lt: ("<", "<="), ast.LtE: ("<=", "<"), ast.Gt: (">", ">="), ast.GtE: (">=", ">"),
       ast.Eq: ("==", "!="), ast.NotEq: ("!=", "=="), ast.In: (" in ", " not in "), ast.NotIn: (" not in ", " in "),
       ast.Is: (" is ", " is not "), ast.IsNot: (" is not ", " is ")}


def _skip_lines(tree: ast.AST) -> set:
    """Lines of docstrings, log calls, raise statements, signatures and module-level constants."""
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Raise,)) or (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                                               and node.func.attr in ("debug", "info", "warning", "error", "exception")):
            skip.update(range(node.lineno, node.end_lineno + 1))
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            skip.update(range(node.lineno, node.end_lineno + 1))
    for node in ast.walk(tree):   # signatures (default values) and decorators
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            first = min([node.lineno] + [d.lineno for d in node.decorator_list])
            skip.update(range(first, node.body[0].lineno))
    for node in tree.body:
        if isinstance(node, (ast.Assign, ast.AnnAssign, ast.Import, ast.ImportFrom)):
            skip.update(range(node.lineno, node.end_lineno + 1))
    return skip


def _enclosing(tree: ast.AST) -> dict:
    out = {}
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for ln in range(node.lineno, node.end_lineno + 1):
                out.setdefault(ln, []).append(node.name)
    return {k: v[-1] for k, v in out.items()}


def candidates(path: Path) -> Iterator[Tuple[int, str, str, str]]:
    """(line number, original line, mutated line, what changed) of every candidate in ``path``."""
    src = path.read_text()
    lines = src.splitlines()
    tree = ast.parse(src)
    skip = _skip_lines(tree)
    for node in ast.walk(tree):
        ln = getattr(node, "lineno", None)
        if ln is None or ln in skip or getattr(node, "end_lineno", ln) != ln:
            continue
        line = lines[ln - 1]
        muts: List[Tuple[int, int, str, str]] = []   # (start col, end col, new text, what)
        if isinstance(node, ast.BinOp) and type(node.op) in BIN:
            a, b = BIN[type(node.op)]
            s, e = node.left.end_col_offset, node.right.col_offset
            seg = line[s:e]
            if seg.count(a) == 1 and (a != "*" or "**" not in seg) and (a != "/" or "//" not in seg):
                muts.append((s, e, seg.replace(a, b), f"`{a.strip()}` -> `{b.strip()}`"))
        elif isinstance(node, ast.Compare) and len(node.ops) == 1 and type(node.ops[0]) in CMP:
            a, b = CMP[type(node.ops[0])]
            s, e = node.left.end_col_offset, node.comparators[0].col_offset
            seg = line[s:e]
            if seg.count(a.strip()) == 1 and (a.strip() not in ("<", ">") or "=" not in seg):
                muts.append((s, e, seg.replace(a.strip(), b.strip()), f"`{a.strip()}` -> `{b.strip()}`"))
        elif isinstance(node, ast.BoolOp) and len(node.values) == 2:
            a, b = ("and", "or") if isinstance(node.op, ast.And) else ("or", "and")
            s, e = node.values[0].end_col_offset, node.values[1].col_offset
            seg = line[s:e]
            if seg.count(a) == 1:
                muts.append((s, e, seg.replace(a, b), f"`{a}` -> `{b}`"))
        elif isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.Not)):
            if not isinstance(node.operand, ast.Constant):
                s, e = node.col_offset, node.operand.col_offset
                muts.append((s, e, "", "unary `-` dropped" if isinstance(node.op, ast.USub) else "`not` dropped"))
        elif isinstance(node, ast.Constant) and type(node.value) in (int, float, bool):
            v = node.value
            s, e = node.col_offset, node.end_col_offset
            if line[s:e] != repr(v) and not (isinstance(v, float) and line[s:e].replace("_", "")):
                continue
            if isinstance(v, bool):
                new = repr(not v)
            elif v == 0:
                new = "1"
            elif v == 1:
                new = "2" if isinstance(v, int) else "2.0"
            elif v == 2:
                new = "1"
            else:
                new = repr(v / 2) if isinstance(v, float) else repr(v + 1)
            muts.append((s, e, new, f"constant {line[s:e]} -> {new}"))
        for s, e, new, what in muts:
            mutated = line[:s] + new + line[e:]
            if mutated != line and src.count(line.strip()) == 1:
                yield ln, line.strip(), mutated.strip(), what


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("-n", type=int, default=6, help="candidates per file (spread over its functions)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", type=Path, default=ROOT, help="tree the paths are relative to (default: this checkout)")
    args = ap.parse_args(argv)
    for f in args.files:
        path = args.root / f
        rel = Path(f).as_posix()
        enc = _enclosing(ast.parse(path.read_text()))
        cands = list(candidates(path))
        rng = random.Random(f"{args.seed}:{rel}")
        rng.shuffle(cands)
        picked, funcs = [], set()
        for c in cands:     # one per function first, then the rest
            if enc.get(c[0]) not in funcs:
                funcs.add(enc.get(c[0]))
                picked.append(c)
        picked += [c for c in cands if c not in picked]
        for ln, orig, mut, what in sorted(picked[:args.n]):
            fn = enc.get(ln, "module level")
            print("[[mutant]]")
            print(f"file = {rel!r}".replace("'", '"'))
            print(f"original = {_toml_str(orig)}")
            print(f"replacement = {_toml_str(mut)}")
            print(f"why = {_toml_str(f'{what} in {fn} (line {ln})')}")
            print()
    return 0


def _toml_str(s: str) -> str:
    if "'" not in s and "\n" not in s:
        return f"'{s}'"
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


if __name__ == "__main__":
    sys.exit(main())
