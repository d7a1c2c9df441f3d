"""Tests of ccdcore.records (typed records stored as JSON) and of the typed product: every field
of CalibrationProduct and Estimates has a type without Any or JSON dictionaries, every record
class of ccdcore round-trips, and a damaged value is one error naming the file and the key."""
from __future__ import annotations

import dataclasses
import importlib
import json
import pkgutil
import typing
from dataclasses import dataclass, field

import numpy as np
import pytest

import ccdcore
from ccdcore.errors import CcdError
from ccdcore.product.make import CalibrationProduct, Estimates
from ccdcore.product.records import ProductEstimates, Provenance
from ccdcore.records import OMIT_NONE, Record, Row


@dataclass(frozen=True)
class _Point(Record):
    level: int
    mu: float
    reason: str | None = None


@dataclass(frozen=True)
class _Fit(Record):
    A: float | None
    cov: tuple[tuple[float | None, ...], ...]
    points: tuple[_Point, ...]
    base: tuple[int | None, float | None]
    by_channel: dict[str, tuple[str, ...]]
    renamed: int = field(default=0, metadata={"key": "n-used"})
    extra: str | None = field(default=None, metadata=OMIT_NONE)


_DOC = {"A": 1, "cov": [[1.0, None], [2, 3.5]],
        "points": [{"level": 1, "mu": 2.5, "reason": None}, {"level": 2, "mu": 3, "reason": "x"}],
        "base": [None, 0.04], "by_channel": {"R": ["a"], "G": []}, "n-used": 3}


def test_round_trip_keeps_keys_order_and_number_types():
    fit = _Fit.from_dict(_DOC, "f.json")
    assert fit.points[1] == _Point(2, 3, "x") and fit.base == (None, 0.04)
    assert fit.renamed == 3 and fit.extra is None
    assert json.dumps(fit.to_dict()) == json.dumps(_DOC)   # "A": 1 stays 1, not 1.0
    assert _Fit.from_dict(json.loads(json.dumps(fit.to_dict()))) == fit
    with_extra = dataclasses.replace(fit, extra="e")
    assert list(with_extra.to_dict())[-1] == "extra"
    assert [k for k, _ in fit.items()] == ["A", "cov", "points", "base", "by_channel", "n-used"]


def test_nan_numpy_scalars_and_defaults():
    fit = _Fit(A=float("nan"), cov=((np.float64(2.0), float("inf")),), points=(),
               base=(np.int64(3), None), by_channel={})
    d = fit.to_dict()
    assert d["A"] is None and d["cov"] == [[2.0, None]] and type(d["base"][0]) is int
    json.dumps(d, allow_nan=False)
    doc = {k: v for k, v in _DOC.items() if k != "n-used"}
    assert _Fit.from_dict(doc).renamed == 0                # a missing key takes its default


@pytest.mark.parametrize("damage, message", [
    (lambda d: {**d, "A": "s"}, "'fit.A' must be a number, got the string 's'"),
    (lambda d: {**d, "points": 3}, "'fit.points' must be an array, got the number 3"),
    (lambda d: {**d, "points": [{"level": 1.5, "mu": 1}]},
     "'fit.points.level' must be an integer, got the number 1.5"),
    (lambda d: {**d, "points": [{"level": True, "mu": 1}]}, "'fit.points.level' must be an integer"),
    (lambda d: {**d, "points": [{"level": 1}]}, "'fit.points.mu' is missing"),
    (lambda d: {k: v for k, v in d.items() if k != "cov"}, "'fit.cov' is missing"),
    (lambda d: {**d, "base": [1, 2, 3]}, "'fit.base' must be an array of 2 values"),
    (lambda d: {**d, "by_channel": {"R": [1]}}, "'fit.by_channel.R' must be a string"),
    (lambda d: [], "'fit' must be an object, got an array"),
])
def test_a_damaged_value_names_the_file_and_the_key(damage, message):
    with pytest.raises(CcdError) as info:
        _Fit.from_dict(damage(dict(_DOC)), "f.json", "fit")
    assert str(info.value).startswith("f.json") and message in str(info.value)


def test_a_field_type_records_cannot_hold_is_a_programming_error():
    @dataclass(frozen=True)
    class Bad(Record):
        values: list[int]

    with pytest.raises(TypeError, match="cannot have the type"):
        Bad.from_dict({"values": [1]})


def test_row_shows_value_error_unit_or_its_text():
    assert Row("read noise", 1.234, 0.05, "e⁻").shown == "1.234 ± 0.050 e⁻"
    assert Row("verdict", 0.4, text="acceptable").shown == "acceptable"
    assert Row("Q", None).shown == "n/a" and str(Row("n", 3)) == "n 3"


# ------------------------------------------------------------------------- the typed product
def _record_classes() -> list[type[Record]]:
    for info in pkgutil.walk_packages(ccdcore.__path__, "ccdcore."):
        if ".simulate" not in info.name:
            importlib.import_module(info.name)
    seen, todo = [], list(Record.__subclasses__())
    while todo:
        cls = todo.pop()
        if cls.__module__.startswith("ccdcore.") and cls not in seen:
            seen.append(cls)
        todo += cls.__subclasses__()
    return seen


def _untyped(tp) -> bool:
    """Whether a type is or holds Any, a bare dict/list, or a dict whose values are not typed
    results (dataclasses) nor arrays: a JSON dictionary."""
    if tp is typing.Any or tp in (dict, list, object):
        return True
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is dict:
        value = args[1]
        if value == tuple[str, ...]:                 # names (a map's frames): fully typed
            return False
        return not (dataclasses.is_dataclass(value) or value is np.ndarray) or _untyped(value)
    return any(_untyped(a) for a in args if a is not Ellipsis)


@pytest.mark.parametrize("cls", [CalibrationProduct, Estimates, ProductEstimates, Provenance])
def test_no_any_nor_json_dictionary_in_the_products_fields(cls):
    from ccdcore.response.methods import ResponseResult

    hints = typing.get_type_hints(cls, localns={"ResponseResult": ResponseResult})
    loose = {f.name: hints[f.name] for f in dataclasses.fields(cls) if _untyped(hints[f.name])}
    assert loose == {}


def test_every_record_class_resolves_its_field_types():
    classes = _record_classes()
    assert len(classes) >= 30
    for cls in classes:
        assert dataclasses.is_dataclass(cls), cls
        hints = typing.get_type_hints(cls)
        assert not [n for n, t in hints.items() if _is_any(t)], cls


def _is_any(tp) -> bool:
    return tp is typing.Any or any(_is_any(a) for a in typing.get_args(tp))


def test_empty_product_records_write_empty_objects():
    assert ProductEstimates().to_dict() == {} and Provenance().to_dict() == {}
    assert ProductEstimates().made() == ()


@pytest.fixture(scope="module", params=["healey94", "delasarte07", "tsin01", "emva1288"])
def demo_product(request, tmp_path_factory):
    from ccdcore.product.make import calibrate
    from ccdcore.simulate import simulate

    root = tmp_path_factory.mktemp(request.param)
    simulate(request.param, root, seed=3, size=(48, 32))
    return calibrate(root), tmp_path_factory.mktemp("out")


def test_a_product_saved_loaded_and_saved_again_writes_the_same_bytes(demo_product):
    from ccdcore.product.make import PRODUCT_FILE, load_product

    product, out = demo_product
    first = product.save(out / "first")
    back = load_product(first)
    assert back.estimates == product.estimates and back.provenance == product.provenance
    assert back.emva1288 == product.emva1288
    assert back.estimates.made() and all(isinstance(s, (Record, dict)) for _, s in
                                         back.estimates.items())
    second = back.save(out / "second")
    assert (second / PRODUCT_FILE).read_bytes() == (first / PRODUCT_FILE).read_bytes()


def test_a_product_load_product_would_refuse_is_not_saved(demo_product):
    product, out = demo_product
    name = product.estimates.made()[0]
    broken = dataclasses.replace(product.estimates, **{name: _broken(getattr(product.estimates,
                                                                             name))})
    with pytest.raises(CcdError, match=rf"'estimates\.{name}\.\w+' must be") as info:
        dataclasses.replace(product, estimates=broken).save(out / "broken")
    assert "calibration.json" in str(info.value) and not (out / "broken").exists()


def _broken(summary: Record) -> Record:
    """``summary`` with None in its first field that must hold a value (a plain number or
    text): a record built by hand, past the checks of from_dict."""
    hints = typing.get_type_hints(type(summary))
    first = next(f.name for f in dataclasses.fields(summary)
                 if hints[f.name] in (int, float, str))
    return dataclasses.replace(summary, **{first: None})
