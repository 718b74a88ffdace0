"""Body shape: Anny's six phenotype values in [0,1], parsed from ``gender=0.2,weight=0.8``."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from hyperbones.errors import ParameterError

PHENOTYPE_KEYS: tuple[str, ...] = ("gender", "age", "muscle", "weight", "height", "proportions")


@dataclass(frozen=True)
class BodyShape:
    """Anny phenotype values, each in [0,1]; 0.5 is Anny's average adult."""

    gender: float = 0.5
    age: float = 0.5
    muscle: float = 0.5
    weight: float = 0.5
    height: float = 0.5
    proportions: float = 0.5

    def __post_init__(self) -> None:
        for key in PHENOTYPE_KEYS:
            value = getattr(self, key)
            if not isinstance(value, (int, float)) or math.isnan(value) or not 0.0 <= value <= 1.0:
                raise ParameterError(f"body {key}={value!r} is out of range: phenotype values lie in [0, 1]")

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}

    def label(self) -> str:
        """Compact text form, e.g. ``gender=0.2,weight=0.8`` (only non-default values)."""
        parts = [f"{k}={v:g}" for k, v in self.as_dict().items() if v != 0.5]
        return ",".join(parts) or "default"

    @classmethod
    def parse(cls, text: str | None) -> "BodyShape":
        """Parse ``key=value`` pairs separated by commas; empty or ``default`` gives the default body."""
        if text is None or text.strip() in ("", "default"):
            return cls()
        values: dict[str, float] = {}
        for item in text.split(","):
            item = item.strip()
            if not item:
                continue
            if "=" not in item:
                raise ParameterError(f"--body: expected key=value, got {item!r} (keys: {', '.join(PHENOTYPE_KEYS)})")
            key, raw = (s.strip() for s in item.split("=", 1))
            if key not in PHENOTYPE_KEYS:
                raise ParameterError(f"--body: unknown key {key!r}; known keys: {', '.join(PHENOTYPE_KEYS)}")
            if key in values:
                raise ParameterError(f"--body: {key!r} given twice")
            try:
                value = float(raw)
            except ValueError:
                raise ParameterError(f"--body: {key}={raw!r} is not a number") from None
            if math.isnan(value) or not 0.0 <= value <= 1.0:
                raise ParameterError(f"--body: {key}={raw} is out of range [0, 1]")
            values[key] = value
        return cls(**values)


def draw_training_shape(uniform, held_out: list[BodyShape], margin: float) -> BodyShape:
    """A phenotype uniform over [0,1]^6 (``uniform()`` in [0, 1), one per key), drawn again until
    it is at least ``margin`` (L2 over the six values) from every ``held_out`` shape."""
    while True:
        values = {key: uniform() for key in PHENOTYPE_KEYS}
        if all(math.dist(values.values(), shape.as_dict().values()) >= margin for shape in held_out):
            return BodyShape(**values)
