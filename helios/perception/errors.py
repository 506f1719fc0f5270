"""Errors raised by perception on bad input: one clear, one-line message each.

All are ``ValueError`` subclasses under :class:`PerceptionError`, which the command line reports
as ``error: ...`` (exit 2) without a traceback.
"""

from __future__ import annotations


class PerceptionError(ValueError):
    """Bad input to a detector or an image-text scorer, or a model that cannot be loaded."""


class UnknownCategoryError(PerceptionError):
    """A class name (or a prompt's category) that the detector or scorer does not know."""


class PromptError(PerceptionError):
    """An empty prompt list, or a prompt that is not of the form "Seems like there is a (object) ahead"."""


class ImageInputError(PerceptionError):
    """An RGB or depth image of the wrong type or shape, or RGB and depth of mismatched sizes."""


class ModelWeightsMissingError(PerceptionError):
    """A real model's weights are not in the local directory the configuration names."""


class ModelWeightsInvalidError(ModelWeightsMissingError):
    """A real model's weights directory holds something the adapter cannot use: another model
    type, no tokenizer or image-processor files, weights that do not load or do not cover the
    model (transformers would fill the gaps with random values and the robot would search blind)."""


class PerceptionDependencyError(PerceptionError):
    """An optional dependency (``transformers``) of the real-model adapters is not installed."""
