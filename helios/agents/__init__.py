"""HELIOS agents: the full method and the paper's ablations as flags on one code path.

Rooms: :mod:`~helios.agents.helios_agent` (phase machine and decision), :mod:`~helios.agents.observer`,
:mod:`~helios.agents.body`, :mod:`~helios.agents.pick`, :mod:`~helios.agents.place`,
:mod:`~helios.agents.candidates`; settings in :mod:`~helios.agents.config`, named variants in
:mod:`~helios.agents.variants`. Nothing is exported here: the command line lists the variant names
without importing torch and the map, so import from the module you need.
"""
