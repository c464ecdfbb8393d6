"""Every configuration field says what it means in a line or two: the text command-line help is made of."""

from __future__ import annotations

import dataclasses
import re

import pytest

from core.field_docs import field_docs
from core.sage.config import AgentConfig, DiffusionConfig, DiscreteConfig, GateConfig, WorldModelConfig

CONFIGS = (AgentConfig, WorldModelConfig, GateConfig, DiscreteConfig, DiffusionConfig)
LONGEST = 240
"""Two source lines of a docstring (120 columns, less the indent and quotes): longer prose belongs in
docs/notes/config_notes.md."""


@pytest.mark.parametrize("config", CONFIGS, ids=lambda cls: cls.__name__)
def test_every_field_has_a_short_docstring_of_its_own(config: type) -> None:
    docs = field_docs(config)
    names = [f.name for f in dataclasses.fields(config)]
    assert [name for name in names if not docs.get(name)] == []
    long = {name: len(docs[name]) for name in names if len(docs[name]) > LONGEST}
    assert long == {}, f"docstrings over {LONGEST} characters: {long}"
    # measurements and their history go to the notes, not into help
    cited = {name: docs[name] for name in names if re.search(r"README|bench/|docs/|experiments/", docs[name])}
    assert cited == {}
