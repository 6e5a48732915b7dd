"""Settings as records keep them: an option added to a dataclass later is left out while it holds its default, so a
record written before it existed reads as the same settings."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from snapflow.reporting.records import added_option, as_record


@dataclass(frozen=True)
class Inner:
    width: int = 8


@dataclass(frozen=True)
class Before:
    steps: int = 10
    schedule: tuple[int, ...] = (2, 4)
    inner: Inner = field(default_factory=Inner)


@dataclass(frozen=True)
class After:  # Before, once two options were added
    steps: int = 10
    schedule: tuple[int, ...] = (2, 4)
    inner: Inner = field(default_factory=Inner)
    average: float | None = added_option(None)
    jumps: float = added_option(0.0)
    extra: dict[str, float] = added_option(default_factory=dict)  # a mutable default, made for each instance


def test_an_added_option_at_its_default_is_left_out_and_the_rest_is_asdict():
    assert as_record(After()) == asdict(Before()) == {"steps": 10, "schedule": (2, 4), "inner": {"width": 8}}
    assert as_record(After(steps=3)) == asdict(Before(steps=3))


def test_an_added_option_that_is_set_is_recorded():
    assert as_record(After(average=0.99)) == {**asdict(Before()), "average": 0.99}
    assert as_record(After(jumps=0.5, average=0.9)) == {**asdict(Before()), "average": 0.9, "jumps": 0.5}
    assert as_record(After(extra={"scale": 2.0})) == {**asdict(Before()), "extra": {"scale": 2.0}}


def test_the_record_is_a_copy():
    @dataclass
    class Mutable:
        values: list[int] = field(default_factory=lambda: [1, 2])

    instance = Mutable()
    as_record(instance)["values"].append(3)
    assert instance.values == [1, 2]
