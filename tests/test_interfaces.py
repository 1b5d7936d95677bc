"""The declared interfaces and the classes that meet them: each member present, methods with the
same parameters (names, order, defaults), properties as properties.

hpcves's interfaces are typing.Protocols (structural: nothing inherits from them) and one abstract
base class (the run loop's Cadence); this test is their type check.
"""
import inspect
import typing

import pytest

from hpcves.campaign.relay import RemoteCaseStore
from hpcves.run import runner
from hpcves.run.schedule import AdaptiveClock, Clock, FixedClock
from hpcves.run.store import CaseRecord, CaseStore


def members(protocol) -> dict:
    """{name: the protocol's attribute} of what the protocol declares (not object's or Protocol's)."""
    skip = set(dir(typing.Protocol)) | {"__abstractmethods__", "__parameters__", "__protocol_attrs__",
                                        "__non_callable_proto_members__", "_is_protocol", "_is_runtime_protocol"}
    return {name: value for name, value in vars(protocol).items() if name not in skip and not name.startswith("__")}


def parameters(function) -> list:
    return [(p.name, p.kind, p.default) for p in inspect.signature(function).parameters.values()]


@pytest.mark.parametrize("protocol, cls", [(Clock, FixedClock), (Clock, AdaptiveClock), (CaseRecord, CaseStore),
                                           (CaseRecord, RemoteCaseStore)], ids=lambda v: v.__name__)
def test_a_class_meets_its_protocol(protocol, cls):
    declared = members(protocol)
    assert declared, protocol
    for name, value in declared.items():
        assert hasattr(cls, name), f"{cls.__name__} lacks {name} of {protocol.__name__}"
        mine = inspect.getattr_static(cls, name)
        if isinstance(value, property):
            assert isinstance(mine, property), f"{cls.__name__}.{name}: not a property"
        else:
            assert parameters(mine) == parameters(value), f"{cls.__name__}.{name}{inspect.signature(mine)}"


def test_every_cadence_of_the_run_loop_declares_due_and_call():
    cadences = [c for c in vars(runner).values() if isinstance(c, type) and issubclass(c, runner.Cadence)
                and c is not runner.Cadence]
    assert len(cadences) >= 8
    for cls in cadences:
        assert not inspect.isabstract(cls), cls
        assert parameters(cls.due) == parameters(runner.Cadence.due)
    with pytest.raises(TypeError):
        runner.Cadence()                               # the interface itself cannot be made
