"""One way to load a data file into a model, and one wording of its errors: FILE: PLACE: PROBLEM."""

from __future__ import annotations

import pytest
from pydantic import BaseModel, ConfigDict, Field

from client_protocol.files import load_model_file, read_document


class Inner(BaseModel):
    model_config = ConfigDict(extra="forbid")
    rate: float = Field(gt=0)


class Config(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str
    inner: Inner


class Refused(ValueError):
    pass


def test_a_good_file_loads_and_json_is_yaml_too(tmp_path):
    (tmp_path / "c.yaml").write_text("name: a\ninner: {rate: 2}\n")
    (tmp_path / "c.json").write_text('{"name": "b", "inner": {"rate": 3}}')
    assert load_model_file(Config, tmp_path / "c.yaml") == Config(name="a", inner=Inner(rate=2))
    assert load_model_file(Config, tmp_path / "c.json").inner.rate == 3


@pytest.mark.parametrize("text, expected", [
    (None, "c.yaml: file not found"),
    ("name: [a\n", "c.yaml: not valid YAML ("),
    ("name: a\ninner: {rate: -1}\n", "c.yaml: inner.rate: Input should be greater than 0"),
    ("inner: {rate: 1, speed: 2}\n", "c.yaml: name: Field required; inner.speed: Extra inputs are not permitted"),
    ("- a\n", "c.yaml: (top level): Input should be a valid dictionary"),
])
def test_every_error_names_the_file_the_place_and_the_problem(tmp_path, text, expected):
    path = tmp_path / "c.yaml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(Refused) as info:
        load_model_file(Config, path, error=Refused)
    assert str(info.value).startswith(f"{tmp_path}/") and expected in str(info.value), str(info.value)


def test_a_caller_words_the_place_and_the_file(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("name: a\ninner: {rate: 0}\n")
    with pytest.raises(ValueError, match=r"^my file: the inner block \(rate\): Input should be greater than 0$"):
        load_model_file(Config, path, shown="my file",
                        place=lambda doc: lambda loc: f"the {loc[0]} block ({loc[1]})")
    with pytest.raises(ValueError, match="^a directory: cannot read"):
        read_document(tmp_path, shown="a directory")
