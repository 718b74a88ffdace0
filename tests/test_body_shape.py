import pytest

from hyperbones.body.shape import PHENOTYPE_KEYS, BodyShape
from hyperbones.errors import ParameterError


def test_parse_values_and_defaults():
    shape = BodyShape.parse("gender=0.2, weight=0.8")
    assert shape.gender == 0.2 and shape.weight == 0.8 and shape.age == 0.5
    assert BodyShape.parse(None) == BodyShape() == BodyShape.parse("default")
    assert set(shape.as_dict()) == set(PHENOTYPE_KEYS)
    assert shape.label() == "gender=0.2,weight=0.8"


@pytest.mark.parametrize("text, phrase", [
    ("foo=0.3", "unknown key 'foo'"),
    ("weight=1.5", "out of range"),
    ("weight=-0.1", "out of range"),
    ("weight=abc", "not a number"),
    ("weight", "expected key=value"),
    ("weight=0.2,weight=0.3", "given twice"),
    ("height=nan", "out of range"),
])
def test_parse_errors_are_one_line(text, phrase):
    with pytest.raises(ParameterError) as info:
        BodyShape.parse(text)
    assert phrase in str(info.value) and "\n" not in str(info.value)


def test_constructor_validates():
    with pytest.raises(ParameterError):
        BodyShape(age=2.0)
