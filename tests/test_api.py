"""triadcal.api: every command's library function, with its own signature and docstring."""

import inspect

import pytest

import triadcal.api as api


@pytest.mark.parametrize("name", sorted(api._LAZY) + ["fit", "simulate", "validate", "example_path"])
def test_every_command_has_a_real_signature_and_a_docstring(name):
    fn = getattr(api, name)
    assert callable(fn) and (fn.__doc__ or "").strip()
    kinds = {p.kind for p in inspect.signature(fn).parameters.values()}
    assert not kinds & {inspect.Parameter.VAR_POSITIONAL}, f"{name} takes *args: its signature says nothing"
    assert name in dir(api)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        api.nope  # noqa: B018
