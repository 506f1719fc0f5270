"""Robot side of the testbed: the HAL contract (``robots.hal``), frame math (``robots.transforms``)
and the Spot model, motion generation and backends (``robots.spot``)."""
