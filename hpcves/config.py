"""Case files (TOML) -> :class:`hpcves.model.params.Case`, with errors a user can act on.

A case file has up to three tables, each optional, each key optional
(defaults are SPEC section 1's published values)::

    [physics]
    shear_rate = 80.0
    psi_bar = 0.3
    excess_length = 0.19385328260599     # the 1/2 : 1/3 ellipse (the default)

    [numerics]
    N = 128             # or "auto": N adapts between N_min = 64 and N_max = 512 (optional keys)
    rtol = 1e-3         # adaptive step under error control; or dt = 5e-4 for a fixed one

    [run]
    t_end = 5.0
    sample_interval = 0.005

Unknown tables or keys, wrong types and out-of-range values raise
:class:`~hpcves.model.params.ConfigError` naming the key.
"""
from __future__ import annotations

import contextlib
import dataclasses
import difflib
import math
import os
import stat
import tomllib
import typing
from pathlib import Path

from hpcves.model.params import Case, ConfigError, Numerics, Physics, RunControl

GROUPS = {"physics": Physics, "numerics": Numerics, "run": RunControl}


def clean_number(value: float) -> float:
    """``value`` to 12 significant digits: 0.30000000000000004 -> 0.3. Swept values, run lengths and
    the points a search or refinement asks for are recorded in files and compared: the same in every run."""
    return float(f"{value:.12g}")


def check_type(where: str, value, kind):
    """Validate (and for numbers, coerce) one TOML value against a field type."""
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where} = {value!r}: must be an integer")
        return value
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where} = {value!r}: must be a number")
        return float(value)
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where} = {value!r}: must be true or false")
        return value
    if kind is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where} = {value!r}: must be a string")
        return value
    arguments = typing.get_args(kind)
    if type(None) in arguments and len(arguments) == 2:       # "float | None": TOML has no null, a value is given
        return check_type(where, value, next(a for a in arguments if a is not type(None)))
    if typing.get_origin(kind) is typing.Literal:
        choices = typing.get_args(kind)
        if value not in choices:
            raise ConfigError(f"{where} = {value!r}: must be one of " + ", ".join(repr(c) for c in choices))
        return value
    raise ConfigError(f"{where}: unsupported parameter type {kind}")   # pragma: no cover


class Problems:
    """Every problem of one input file, so that a user mends them all in one go.

    Each independent part is checked inside ``with problems.check():`` -- a ConfigError
    there is noted and the rest is still checked -- and :meth:`raise_any` raises one
    ConfigError holding them all, a line each (the CLI prints each line as an ``Error:``).
    Parts that need an earlier one to be sound (the cases of a sweep need its values) are
    checked after ``raise_any``; a range check inside one table stops at its first.
    """

    def __init__(self):
        self.found: list[str] = []

    @contextlib.contextmanager
    def check(self, prefix: str = ""):
        try:
            yield
        except ConfigError as exc:
            self.found += [prefix + line for line in str(exc).splitlines()]

    def raise_any(self) -> None:
        if self.found:
            raise ConfigError("\n".join(self.found))


def with_prefix(prefix: str, exc: ConfigError) -> ConfigError:
    """A ConfigError of ``exc``'s problems with ``prefix`` before each (one line per problem)."""
    return ConfigError("\n".join(prefix + line for line in str(exc).splitlines()))


def refuse_unknown(values: dict, known, where: str) -> None:
    """ConfigError naming every key of ``values`` not in ``known`` (and the known ones), e.g.
    ``[physics]: unknown keys shear (did you mean shear_rate?), tension (known: ...)``: the one check of
    every table."""
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ConfigError(f"{where}: unknown key{'s' * (len(unknown) > 1)} "
                          f"{', '.join(_home(key, where) or did_you_mean(key, known) for key in unknown)} "
                          f"(known: {', '.join(known)})")


def _home(key: str, where: str) -> str:
    """``N (it belongs in [numerics])`` for a key of a case's table given in another table ('' else)."""
    for table, cls in GROUPS.items():
        names = {f.name for f in dataclasses.fields(cls)} | ({"N_min"} if table == "numerics" else set())
        if key in names and not where.startswith(f"[{table}]"):
            return f"{key} (it belongs in [{table}])"
    return ""


def did_you_mean(name: str, known) -> str:
    """``name``, followed by " (did you mean X?)" where one of ``known`` is close to it: a typo or a
    missing underscore (difflib's ratio >= 0.75: psibar -> psi_bar, rtoll -> rtol) or a word left out
    (the name inside a known one: shear -> shear_rate); nothing for a name like none of them."""
    known = list(known)
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.75)
    if not close:
        close = [k for k in known if len(name) >= 3 and name.strip("[]") in k]
    return f"{name} (did you mean {close[0]}?)" if len(close) >= 1 else name


def from_table(cls, values: dict, where: str, prefix: str):
    """A settings dataclass from a TOML table: unknown keys refused, every value type-checked
    (messages name ``where``, e.g. "[search]", and ``prefix.key``)."""
    types = typing.get_type_hints(cls)
    refuse_unknown(values, sorted(f.name for f in dataclasses.fields(cls)), where)
    checked = {key: check_type(f"{prefix}.{key}", value, types[key]) for key, value in values.items()}
    for key, value in checked.items():         # inf or nan: a threshold no case can meet, or always meets
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(f"{where}: {prefix}.{key} = {value!r}: must be a finite number")
    return cls(**checked)


#: numerics.N = "auto": the bounds N adapts between unless N_min / N_max are given
AUTO_N = (64, 512)


def auto_N(values: dict) -> dict:
    """[numerics] with N = "auto" (and the optional N_min) as Numerics takes it: N = N_min, N_max."""
    if isinstance(values.get("N"), str) and values["N"] != "auto":
        raise ConfigError(f'numerics.N = {values["N"]!r}: must be an integer, or "auto" (N adapts during the run)')
    if values.get("N") != "auto":
        if "N_min" in values:
            raise ConfigError(f"numerics.N_min = {values['N_min']!r}: only with N = \"auto\" (the smallest N "
                              "it adapts to); a fixed N is N itself")
        return values
    out = dict(values)
    del out["N"]
    out["N"] = out.pop("N_min", AUTO_N[0])
    if "N_min" in values:                       # checked under its own name (Numerics would say numerics.N)
        N_min = check_type("numerics.N_min", values["N_min"], int)
        if not (16 <= N_min <= 4096 and N_min % 2 == 0):
            raise ConfigError(f"numerics.N_min = {N_min}: must be even, from 16 to 4096")
    out.setdefault("N_max", AUTO_N[1])
    if out["N_max"] == 0:
        raise ConfigError('numerics.N_max = 0 with N = "auto": give the largest N it may grow to (default 512)')
    return out


def group_from_dict(name: str, values: dict, base=None):
    """Build one parameter group from a dict, starting from ``base`` (or the defaults)."""
    cls = GROUPS[name]
    if not isinstance(values, dict):
        raise ConfigError(f"[{name}] must be a table, got {type(values).__name__}")
    if name == "numerics":
        values = auto_N(values)
    types = typing.get_type_hints(cls)
    problems = Problems()
    with problems.check():
        refuse_unknown(values, [f.name for f in dataclasses.fields(cls)], f"[{name}]")
    kwargs = {}
    for key, value in values.items():
        if key in types:
            with problems.check():
                kwargs[key] = check_type(f"{name}.{key}", value, types[key])
    problems.raise_any()
    if name == "numerics" and "rtol" in kwargs and "dt" in kwargs:
        raise ConfigError(f"[numerics] sets both dt = {kwargs['dt']:g} (a fixed step) and rtol = {kwargs['rtol']:g} "
                          "(an adaptive one): keep one; dt_max bounds the adaptive step")
    base = base if base is not None else cls()
    return dataclasses.replace(base, **kwargs)


#: what a file's top-level ``preset = "<name>"`` fills in, key by key, where the file does not give the
#: key itself: "publication" is the publication's numerics as its authors' code computes them (the
#: linear law, their smoothed start and its phase coordinate, their time integration at dt = 1e-5
#: and their filter; the area projection stays: without it their scheme's area drifts by ~10 % per unit
#: time at Delta = 2.3, S = 40 -- numerics.area_correction = false shows that; docs/numerics.md,
#: "The publication's scheme")
PRESETS = {
    "publication": {
        "physics": {"bending_law": "linear", "initial_shape": "smoothed", "psi_init_coordinate": "ellipse_parameter"},
        "numerics": {"scheme": "ifab2", "dt": 1e-5, "filter_order": 25},
    },
}


def expand_preset(data: dict) -> dict:
    """``data`` with its ``preset`` (if any) replaced by the keys the preset fills in (PRESETS)."""
    if "preset" not in data:
        return data
    data = dict(data)
    name = data.pop("preset")
    if name not in PRESETS:
        raise ConfigError(f"preset = {name!r}: must be one of {', '.join(map(repr, PRESETS))}")
    numerics = data.get("numerics", {})
    if isinstance(numerics, dict) and "rtol" in numerics:
        raise ConfigError(f"preset = {name!r} takes fixed steps (numerics.dt = {PRESETS[name]['numerics']['dt']:g}): "
                          "leave numerics.rtol out")
    for table, values in PRESETS[name].items():
        given = data.get(table, {})
        if isinstance(given, dict):
            data[table] = {**values, **given}
    return data


def case_from_dict(data: dict, base: Case | None = None) -> Case:
    """A :class:`Case` from a nested dict such as a parsed TOML document (its ``preset`` expanded)."""
    data = expand_preset(data)
    problems = Problems()
    unknown = sorted(set(data) - set(GROUPS))
    if unknown:
        problems.found.append("unknown table" + ("s" if len(unknown) > 1 else "") + ": "
                              + ", ".join(did_you_mean(f"[{u}]", [f"[{g}]" for g in GROUPS]) for u in unknown)
                              + " (known: [physics], [numerics], [run]; and preset = \"publication\")")
    base = base if base is not None else Case()
    groups = {}
    for name in GROUPS:
        with problems.check():
            groups[name] = group_from_dict(name, data.get(name, {}), getattr(base, name))
    problems.raise_any()
    return Case(**groups)


def not_a_regular_file(path) -> str:
    """What ``path`` is when it exists and is not a regular file (or a link to one): a device, a FIFO,
    a socket; '' otherwise. Opened as HDF5, a device is written to (``/dev/null`` crashed h5py on close)."""
    mode = os.stat(path).st_mode
    for test, kind in ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return ""


def read_text(path: Path) -> str:
    """The text of an input file; a missing, special (a device, a pipe) or unreadable one is a
    ConfigError naming it."""
    try:
        kind = not_a_regular_file(path)
        if kind:
            raise ConfigError(f"{path}: {kind}, not a TOML file")
        return path.read_text(encoding="utf-8-sig")     # a byte-order mark (some editors write one) dropped
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a TOML file") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset {exc.start}); "
                          "TOML files are UTF-8") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None


def read_settings(path: str | Path, what: str) -> str:
    """The text of an input file that sets something: one that is empty or holds only comments is
    refused (a wrong path, not a request for every default), as is a path ending in '/' (which
    pathlib would quietly drop). ``what``: the tables it could hold."""
    if isinstance(path, str) and path.endswith(("/", os.sep)):
        raise ConfigError(f"{path}: ends in '/', the name of a directory, not of a TOML file")
    path = Path(path)
    text = read_text(path)
    try:
        empty = not tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        empty = False                        # its parser's message, from the caller
    if empty:
        raise ConfigError(f"{path}: sets nothing (empty, or comments only); give at least one of {what}")
    return text


def load_case(path: str | Path) -> Case:
    """Read and validate a case file."""
    return case_from_toml(read_settings(path, "[physics], [numerics], [run]"), source=str(Path(path)))


#: What a stored case (written out in full by :func:`case_to_toml`) meant by an option it
#: does not name: the behaviour of hpcves before the option existed, not today's default.
STORED_BEFORE_OPTION = {"physics": {"bending_law": "linear"}}


def case_from_toml(text: str, source: str = "<string>", stored: bool = False) -> Case:
    """A case from TOML text. ``stored``: the full text of a case in a file, where an option it
    does not name takes its value from before the option existed (STORED_BEFORE_OPTION)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML ({exc})") from None
    if stored:
        for group, options in STORED_BEFORE_OPTION.items():
            table = data.get(group)
            if isinstance(table, dict):
                for key, value in options.items():
                    table.setdefault(key, value)
    try:
        return case_from_dict(data)
    except ConfigError as exc:
        raise with_prefix(f"{source}: ", exc) from None


def case_to_toml(case: Case) -> str:
    """The full case as TOML text (every parameter written out), readable by :func:`case_from_toml`."""
    lines = []
    for name, values in case.to_dict().items():
        lines.append(f"[{name}]")
        for key, value in values.items():
            if value is None:                       # TOML has no null: an unset option is left out
                continue
            if name == "numerics" and key == "dt" and case.numerics.adaptive:
                continue                            # not used, and refused beside rtol
            lines.append(f"{key} = {_toml_value(value)}")
        lines.append("")
    return "\n".join(lines)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, float):
        return repr(float(value))   # shortest repr round-trips exactly (numpy's float64 is a float whose
                                    # repr is "np.float64(...)")
    return str(value)
