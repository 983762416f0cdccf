"""One field of a technique's options dataclass, with what its ``bake`` flag needs."""

from __future__ import annotations

from dataclasses import field


def option(default, help: str, *, choices: tuple | None = None, flag: bool = False, range=None):
    """A frozen options dataclass's field: its default and its CLI flag ``--<technique>-<field>``.

    Parameters
    ----------
    default
        The default of the option (and of its TOML key and flag).
    help : str
        The flag's help; ``{default}`` in it (format spec allowed: ``{default:g}``) is the default.
    choices : tuple, optional
        The values the flag accepts.
    flag : bool
        A boolean the flag turns on (``store_true``; absent, the config's value stands).
    range : core.ranges.Range, optional
        The values a number may take (`options.check_value` refuses others; the flag's help gives it).
    """
    return field(default=default, metadata={"help": help, "choices": choices, "flag": flag,
                                            **({"range": range} if range is not None else {})})
