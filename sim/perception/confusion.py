"""The confusion table of the simulated detector: which categories each category is mistaken for.

It starts from the catalogue's look-alike families (``sim.scenes.catalog.LOOKALIKES``: mug / cup /
glass / jar, bowl / plate, table / desk / counter, stool / chair, shelf / cabinet / filing cabinet,
sofa / bed, ...), every pair of a family with weight 1, and adds a few cross-family confusions
open-vocabulary detectors make (``EXTRA_LOOKALIKES``, weight
``SimPerceptionConfig.lookalike_weight_extra``): a banana for a toy, a counter for a cabinet, a
chair or a stool for a sofa, a stool for a table, a plastic box (furniture) for a box (object), ...
Furniture confusions drive both the persistent bad-view labels and the phantom receptacles on
parts of other furniture (``SimPerceptionConfig.receptacle_part_false_positive``).
"""

from __future__ import annotations

from sim.scenes.catalog import ALL_CATEGORIES, LOOKALIKES, OBJECT_CATEGORIES, RECEPTACLE_CATEGORIES

EXTRA_LOOKALIKES: tuple[tuple[str, str], ...] = (
    ("banana", "toy"), ("banana", "remote"), ("counter", "cabinet"), ("desk", "filing cabinet"),
    ("plastic box", "box"), ("chair", "sofa"), ("shelf", "desk"), ("bowl", "mug"), ("vase", "glass"),
    ("apple", "toy"), ("book", "phone"), ("soap", "box"),
    # furniture: seats (chair / stool / sofa), a stool for a small table, a desk for a low cabinet
    ("stool", "sofa"), ("table", "stool"), ("cabinet", "desk"),
)


class ConfusionTable:
    """category -> {look-alike category: weight}; symmetric, no self-confusions."""

    def __init__(self, extra_weight: float = 0.5,
                 families: tuple[tuple[str, ...], ...] = LOOKALIKES,
                 extra: tuple[tuple[str, str], ...] = EXTRA_LOOKALIKES):
        known = set(ALL_CATEGORIES)
        table: dict[str, dict[str, float]] = {c: {} for c in ALL_CATEGORIES}
        for fam in families:
            for a in fam:
                for b in fam:
                    if a != b:
                        table[a][b] = max(table[a].get(b, 0.0), 1.0)
        if extra_weight > 0:
            for a, b in extra:
                for x, y in ((a, b), (b, a)):
                    if x not in known or y not in known:
                        raise ValueError(f"confusion pair ({a!r}, {b!r}) names an unknown category")
                    table[x][y] = max(table[x].get(y, 0.0), extra_weight)
        self._table = table

    def lookalikes(self, category: str) -> dict[str, float]:
        return dict(self._table.get(category, {}))

    def weights(self, category: str) -> dict[str, float]:
        """Look-alikes of ``category`` with their weights (read-only view; do not modify)."""
        return self._table.get(category, {})

    def could_be_labelled(self, category: str, queried: frozenset[str]) -> bool:
        """Whether an instance of ``category`` can come out labelled as one of ``queried``."""
        return category in queried or any(c in queried for c in self._table.get(category, ()))

    def as_rows(self) -> list[tuple[str, str]]:
        return [(c, ", ".join(f"{k} ({w:g})" for k, w in sorted(v.items()))) for c, v in self._table.items()]


def category_group(category: str) -> str:
    """``object`` (small, graspable-size things) or ``receptacle`` (furniture)."""
    if category in OBJECT_CATEGORIES:
        return "object"
    if category in RECEPTACLE_CATEGORIES:
        return "receptacle"
    raise KeyError(category)
