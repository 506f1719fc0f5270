"""The value-map prompt of the paper, "Seems like there is a (object) ahead", and its inverse.

HELIOS (like VLFM) scores each RGB frame against one prompt per value-map layer; the simulated
image-text scorer reads the category back out of the prompt, so prompts must keep this form.
"""

from __future__ import annotations

import re
from typing import Sequence

from helios.perception.errors import PromptError

VALUE_PROMPT_TEMPLATE = "Seems like there is a {} ahead"
"""*paper* The prompt used to build the semantic value maps (one per search target)."""

_PROMPT_RE = re.compile(r"^\s*seems\s+like\s+there\s+is\s+(?:a|an)\s+\(?\s*(?P<category>[^()]+?)\s*\)?\s+ahead\s*[.!]?\s*$",
                        re.IGNORECASE)


def value_prompt(category: str, template: str = VALUE_PROMPT_TEMPLATE) -> str:
    """The prompt for one search target, e.g. ``"Seems like there is a counter ahead"``."""
    if not isinstance(category, str) or not category.strip():
        raise PromptError(f"a prompt needs a non-empty category name, got {category!r}")
    if template.count("{}") != 1:
        raise PromptError(f"a prompt template needs exactly one '{{}}' for the category, got {template!r}")
    return template.format(" ".join(category.strip().split()))


def parse_value_prompt(prompt: str) -> str:
    """The category named by a value prompt, normalised (lower case, single spaces, '_' -> ' ').

    Accepts "a" or "an", optional parentheses around the category and a trailing period.
    """
    if not isinstance(prompt, str):
        raise PromptError(f"prompts must be strings, got {type(prompt).__name__} {prompt!r}")
    m = _PROMPT_RE.match(prompt)
    if m is None:
        raise PromptError(f"cannot interpret prompt {prompt!r}; expected the form "
                          f"{VALUE_PROMPT_TEMPLATE.format('(object)')!r}, e.g. {value_prompt('counter')!r}")
    return normalise_category(m.group("category"))


def normalise_category(name: str) -> str:
    return " ".join(name.replace("_", " ").lower().split())


def check_prompts(prompts: Sequence[str]) -> list[str]:
    """A non-empty list of prompt strings (a bare string is refused: it would be read letter by letter)."""
    if isinstance(prompts, (str, bytes)):
        raise PromptError(f"prompts must be a list of strings, got a single string {prompts!r}; wrap it in a list")
    try:
        items = list(prompts)
    except TypeError:
        raise PromptError(f"prompts must be a list of strings, got {type(prompts).__name__}") from None
    if not items:
        raise PromptError("the prompt list is empty; give at least one prompt such as "
                          f"{value_prompt('counter')!r}")
    for i, p in enumerate(items):
        if not isinstance(p, str) or not p.strip():
            raise PromptError(f"prompts[{i}] must be a non-empty string, got {p!r}")
    return items
