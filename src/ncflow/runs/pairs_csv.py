"""The pairs csv that ``ncflow batch`` and ``ncflow benchmark`` read: one row per pair to match.

Columns: ``name, source, target, skeleton`` (``ncflow batch``; an empty skeleton is suggested from the
source), plus ``gt`` and optionally
``gt_format`` and ``dataset`` for ``ncflow benchmark`` (the file :func:`ncflow.synthetic.pairs.write_pairs`
and ``ncflow make-pairs`` write). Other columns are allowed and ignored. Paths are relative to the
csv's folder (absolute paths are taken as they are: a csv is a list of inputs the user chose, like a
command line) and are returned absolute, so that workers in another folder or on another machine of a
shared file system read the same files.

Every row is checked before anything runs: the columns, non-empty values, existing regular files,
names usable as folder names (letters, digits, ``.``, ``_``, ``-``; at most 100 characters; no path
separators) and unique names (also ignoring case, since the run folders may live on a file system
that does not tell ``A`` from ``a``). The file itself is bounded: at most :data:`MAX_CSV_BYTES` and
:data:`MAX_PAIRS` rows. Each problem is one :class:`~ncflow.errors.InputError` line naming the csv
(and the line).
"""

from __future__ import annotations

import csv
import dataclasses
import os
import re
import stat
from pathlib import Path

from ncflow.errors import InputError, first_line
from ncflow.io.ground_truth import GT_FORMATS

PAIR_COLUMNS = ("name", "source", "target", "skeleton")
GT_COLUMNS = ("gt",)
OPTIONAL_COLUMNS = ("gt_format", "dataset")
MAX_CSV_BYTES = 64 << 20
MAX_PAIRS = 100_000
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")


@dataclasses.dataclass(frozen=True)
class PairSpec:
    """One row of a pairs csv, paths absolute (resolved against the csv's folder).

    ``gt`` is ``"identity"``, a path, a pair of paths (template maps), or None (a batch csv
    without ground truth).
    """

    name: str
    source: str
    target: str
    skeleton: str | None  # None (an empty cell): suggested from the source
    gt: str | tuple[str, str] | None
    gt_format: str | None
    dataset: str


def _resolve(base: Path, value: str) -> str:
    p = Path(value).expanduser()
    return os.path.abspath(p if p.is_absolute() else base / p)


def _check_file(file: str, key: str, where: str, path: Path) -> None:
    try:
        mode = os.stat(file).st_mode
    except (OSError, ValueError):
        raise InputError(f"{where}: {key} file not found: {file}", path) from None
    if not stat.S_ISREG(mode):
        raise InputError(f"{where}: {key} is not a regular file: {file}", path)


def _parse_row(row: dict, line: int, base: Path, path: Path, ground_truth: bool) -> PairSpec:
    where = f"line {line}"
    required = PAIR_COLUMNS + (GT_COLUMNS if ground_truth else ())
    values = {k: (row.get(k) or "").strip() for k in PAIR_COLUMNS + GT_COLUMNS + OPTIONAL_COLUMNS}
    for key in required:
        if not values[key] and key != "skeleton":
            raise InputError(f"{where}: empty {key!r}", path)
    name = values["name"]
    if not _NAME_RE.match(name):
        raise InputError(
            f"{where}: pair name {name[:60]!r} must be 1-100 letters, digits, '.', '_' or '-' starting with a "
            "letter or digit (it names a folder)",
            path,
        )
    files = {k: _resolve(base, values[k]) for k in ("source", "target", "skeleton") if values[k]}
    gt: str | tuple[str, str] | None = None
    fmt = values["gt_format"] or None
    if ground_truth:
        if fmt is not None and fmt not in GT_FORMATS:
            raise InputError(f"{where}: unknown gt_format {fmt[:40]!r}; use one of {', '.join(GT_FORMATS)}", path)
        if fmt == "identity" or (fmt is None and values["gt"].lower() == "identity"):
            gt = "identity"
        elif fmt == "template":
            parts = [s.strip() for s in values["gt"].split(";") if s.strip()]
            if len(parts) != 2:
                raise InputError(f"{where}: gt_format template needs two .vts files separated by ';'", path)
            gt = (_resolve(base, parts[0]), _resolve(base, parts[1]))
        else:
            gt = _resolve(base, values["gt"])
        gts = [] if gt == "identity" else ([gt] if isinstance(gt, str) else list(gt))
        files.update({f"gt{i or ''}": g for i, g in enumerate(gts)})
    for key, file in files.items():
        _check_file(file, key.rstrip("0123456789") if key.startswith("gt") else key, where, path)
    skeleton = files.get("skeleton")
    return PairSpec(name, files["source"], files["target"], skeleton, gt, fmt, values["dataset"] or "default")


def read_pairs_csv(path: str | os.PathLike, ground_truth: bool = True) -> list[PairSpec]:
    """Read and check a pairs csv (see the module docstring).

    Args:
        path: the csv.
        ground_truth: require the ``gt`` column (``ncflow benchmark``); without it (``ncflow batch``)
            ``gt`` and ``gt_format`` are ignored and every :attr:`PairSpec.gt` is None.

    Returns:
        the pairs, in file order.

    Raises:
        InputError: one line naming the csv (and the line) on the first problem.
    """
    path = Path(path)
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        raise InputError("no such file", path) from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError("is not a regular file (expected a pairs csv)", path)
    if st.st_size > MAX_CSV_BYTES:
        raise InputError(f"is {st.st_size / 2**20:.0f} MiB; a pairs csv is at most {MAX_CSV_BYTES >> 20} MiB", path)
    required = PAIR_COLUMNS + (GT_COLUMNS if ground_truth else ())
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            header = [(h or "").strip() for h in (reader.fieldnames or [])]
            reader.fieldnames = header
            missing = [c for c in required if c not in header]
            if missing:
                raise InputError(
                    f"missing column(s) {', '.join(missing)} (expected {', '.join(required)}"
                    + (f"[, {', '.join(OPTIONAL_COLUMNS)}]" if ground_truth else "")
                    + "; other columns are ignored)",
                    path,
                )
            duplicated = sorted({c for c in header if c and header.count(c) > 1})
            if duplicated:
                raise InputError(f"column(s) {', '.join(duplicated)} appear more than once", path)
            rows = []
            for row in reader:
                if any((v or "").strip() for v in row.values() if isinstance(v, str)):
                    rows.append((reader.line_num, row))
                    if len(rows) > MAX_PAIRS:
                        raise InputError(f"more than {MAX_PAIRS} pairs; split the csv", path)
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"cannot read csv ({first_line(exc)})", path) from None
    except OSError as exc:
        raise InputError(f"cannot read csv ({exc.strerror or first_line(exc)})", path) from None
    if not rows:
        raise InputError("no pairs listed", path)
    pairs = [_parse_row(row, line, path.parent.absolute(), path, ground_truth) for line, row in rows]
    seen: dict[str, str] = {}
    for p in pairs:
        folded = p.name.casefold()
        if folded in seen:
            same = "" if seen[folded] == p.name else f" (as {seen[folded]!r}, ignoring case)"
            raise InputError(f"duplicate pair name {p.name!r}{same}; names label the result folders", path)
        seen[folded] = p.name
    return pairs
