"""Field constructors of the configuration dataclasses: a default plus the value rules that
``config.validate`` enforces from the field's metadata (Drake's YAML loader checks types only)."""

from dataclasses import Field, field


def vector(*values) -> Field:
    """A list field of fixed length with default `values`."""
    return field(default_factory=lambda: list(values), metadata={"length": len(values)})


def number(default, **rules) -> Field:
    """A scalar field; rules: positive=True, nonnegative=True, minimum=, maximum=, noise_std=True,
    tick_multiple=N (a whole number >= N of onboard ticks)."""
    return field(default=default, metadata=rules)


def noise_stds(*values) -> Field:
    """A vector of noise standard deviations (>= 0, see ``config.NOISE_STD_RANGE``)."""
    return field(
        default_factory=lambda: list(values),
        metadata={"length": len(values), "nonnegative": True, "noise_std": True},
    )
