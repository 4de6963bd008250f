"""The suite's one check of a refusal: a call raises a ValueError (not a subclass's sibling, not another type)
whose message holds every given word."""

import re

import pytest


def raises(fn, *words) -> str:
    """``fn()`` raises a ValueError (not another type) whose message holds every word (regex-escaped); returns
    the message."""
    with pytest.raises(ValueError) as err:
        fn()
    assert type(err.value) is ValueError
    for w in words:
        assert re.search(re.escape(str(w)), str(err.value)), (w, str(err.value))
    return str(err.value)
