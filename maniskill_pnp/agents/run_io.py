"""What every training recipe does with its run folder: config (de)serialization, field help texts, loggers and
atomic writes. One place, so the conveyor and clutter recipes (and their evaluations) cannot drift apart."""

from __future__ import annotations

import ast
import dataclasses
import importlib.util
import inspect
import json
import os
import re
import tempfile
import textwrap
import types
import typing
from pathlib import Path

from torchrl.record.loggers import Logger
from torchrl.record.loggers.csv import CSVLogger


class RunConfig:
    """Mixin for a frozen recipe config dataclass with an ``out`` folder and a ``run_name`` property.

    The dataclass's ``__post_init__`` normalizes field types (``out`` to a Path, sequences to tuples), so a config
    read back from JSON equals the one that was saved.
    """

    out: Path
    run_name: str

    @property
    def run_dir(self) -> Path:
        """The run folder ``out / run_name``."""
        return self.out / self.run_name

    def to_json(self) -> dict:
        """The config as a JSON-ready dict (paths as strings)."""
        d = dataclasses.asdict(self)
        d["out"] = str(self.out)
        return d

    @classmethod
    def from_json(cls, d: dict):
        """The config from :meth:`to_json`'s dict; ValueError naming any unknown or mistyped field."""
        cls._check_values(d)
        return cls(**d)

    @classmethod
    def _check_values(cls, d) -> None:
        if not isinstance(d, dict):
            raise ValueError(f"a {cls.__name__} must be a mapping of field names to values, got {type(d).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown config fields {unknown}; known: {sorted(known)}")
        hints = typing.get_type_hints(cls)
        for name, value in d.items():
            if not _fits(value, hints[name]):
                raise ValueError(f"config field {name!r} must be {_type_name(hints[name])}, got {value!r}")

    @classmethod
    def values_from_file(cls, path: str | os.PathLike) -> dict:
        """The field values of a YAML or JSON config file, checked against the fields (names and types) but not yet
        a config; ValueError naming the file and the problem (parse error, unknown or mistyped field)."""
        import yaml

        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"config file {path} does not exist")
        try:
            d = yaml.safe_load(path.read_text()) or {}
        except yaml.YAMLError as e:
            raise ValueError(f"config file {path} is not valid YAML/JSON: {e}") from e
        try:
            cls._check_values(d)
        except ValueError as e:
            raise ValueError(f"config file {path}: {e}") from e
        return d

    @classmethod
    def from_file(cls, path: str | os.PathLike, **overrides):
        """The config from a YAML or JSON file (missing fields keep their defaults), with ``overrides`` applied."""
        d = cls.values_from_file(path)
        try:
            return cls.from_json({**d, **overrides})
        except (TypeError, ValueError) as e:
            raise ValueError(f"config file {path}: {e}") from e


def _fits(value, hint) -> bool:
    """Whether a JSON/YAML value can stand for a field annotated ``hint`` (ints for floats, strings for paths)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_fits(value, a) for a in args)
    if hint is type(None):
        return value is None
    if origin is tuple:
        return isinstance(value, (list, tuple)) and all(_fits(v, args[0]) for v in value)
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is Path:
        return isinstance(value, (str, Path))
    return isinstance(value, hint) if isinstance(hint, type) else True


def _type_name(hint) -> str:
    return getattr(hint, "__name__", None) or str(hint).replace("typing.", "")


def field_docs(cls) -> dict[str, str]:
    """The description of each field of a dataclass (the CLI's ``--help`` text: one source of truth): the docstring
    under the field, else the field's entry in the ``Attributes:`` section of the class docstring."""
    docs = {}
    section = re.search(r"^Attributes:\n((?:[ \t]+.*\n?|\n)*)", inspect.cleandoc(cls.__doc__ or ""), re.M)
    if section:
        for entry in re.finditer(r"^    (\w+): (.*(?:\n {8,}.*)*)", section.group(1), re.M):
            docs[entry.group(1)] = " ".join(entry.group(2).split())
    body = ast.parse(textwrap.dedent(inspect.getsource(cls))).body[0].body
    for node, after in zip(body, body[1:]):
        if isinstance(node, ast.AnnAssign) and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant):
            docs[node.target.id] = " ".join(str(after.value.value).split())
    return docs


#: The loggers a recipe's ``logger`` field may name: CSV files in the run folder (read back by the evaluation and
#: plot commands) or TorchRL's TensorboardLogger (needs the ``tensorboard`` extra).
LOGGERS = ("csv", "tensorboard")


class MissingExtraError(ImportError, ValueError):
    """An option needs an optional extra of the package that is not installed (also a ValueError: a bad option value
    on this machine, reported as such by the command line)."""


def check_logger(kind) -> None:
    """ValueError naming the valid values unless ``kind`` is one of :data:`LOGGERS` (a config's ``__post_init__``)."""
    if kind not in LOGGERS:
        raise ValueError(f"unknown logger {kind!r}; valid: {list(LOGGERS)}")


def _tensorboard_installed() -> bool:
    return importlib.util.find_spec("tensorboard") is not None


def require_logger(kind: str) -> None:
    """:func:`check_logger`, and :class:`MissingExtraError` naming the extra to install when ``kind`` needs a package
    that is missing; a recipe calls it before building anything, so the error comes at once."""
    check_logger(kind)
    if kind == "tensorboard" and not _tensorboard_installed():
        raise MissingExtraError(
            "logger 'tensorboard' needs the tensorboard package: pip install 'maniskill_pnp[tensorboard]' "
            "(or use logger 'csv')"
        )


def make_logger(run_dir: Path, kind: str) -> Logger:
    """TorchRL's logger ``kind`` writing into the run folder.

    ``"csv"``: :class:`~torchrl.record.loggers.csv.CSVLogger`, one ``scalars/<name>.csv`` per scalar (what the
    evaluation and plot commands read back). ``"tensorboard"``:
    :class:`~torchrl.record.loggers.tensorboard.TensorboardLogger`, an ``events.out.tfevents.*`` file in the run
    folder. Raises what :func:`require_logger` raises. Close the logger when training ends, so TensorBoard's buffered
    events reach the file.
    """
    require_logger(kind)
    run_dir = Path(run_dir)
    if kind == "tensorboard":
        from torchrl.record.loggers.tensorboard import TensorboardLogger

        return TensorboardLogger(exp_name=run_dir.name, log_dir=str(run_dir.parent))
    return CSVLogger(exp_name=run_dir.name, log_dir=str(run_dir.parent))


def atomic_write_bytes(path: Path, write) -> None:
    """Write through ``write(file)`` into a temp file beside ``path``, then ``os.replace`` it into place.

    The file gets the permissions of an ordinary new file (``0o666`` less the umask), not the owner-only mode of
    the temp file, so run folders stay readable by whoever may read the folder.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0o022)  # reading the umask means setting it; put it straight back
    os.umask(mask)
    return mask


def write_json(path: Path, obj) -> None:
    """``obj`` as indented JSON at ``path``, written atomically."""
    atomic_write_bytes(path, lambda f: f.write(json.dumps(obj, indent=2).encode()))


def require_positive(config, names) -> None:
    """ValueError naming the first of ``names`` whose value on ``config`` is below 1 (counts, intervals, sizes)."""
    for name in names:
        if getattr(config, name) < 1:
            raise ValueError(f"{name} must be >= 1, got {getattr(config, name)}")
