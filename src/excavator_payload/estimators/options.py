"""An estimator's command-line options (``--name value`` after ``train NAME``): :class:`Option`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from excavator_payload.errors import EstimatorError


@dataclass(frozen=True)
class Option:
    """A command-line option of an estimator (``--name value`` after ``train NAME``).

    Parameters
    ----------
    type : type
        Type the raw value is converted to (``bool``, ``int``, ``float``, ``str``, ``list``, ...).
    default : Any
        Value when the option is not given.
    help : str
        One-line help text shown on the command line.
    choices : tuple or None
        Allowed values (None: any).
    """

    type: type
    default: Any
    help: str
    choices: tuple | None = None

    def parse(self, name: str, raw: Any) -> Any:
        """Convert the raw value ``raw`` of option ``name`` to the option's type (booleans from
        ``1/0/true/false/yes/no``, lists from comma-separated text) and check it is one of
        ``choices``; :class:`EstimatorError` otherwise.

        Parameters
        ----------
        name : str
            Option name (underscores; shown as ``--name-with-dashes`` in errors).
        raw : Any
            Raw value, usually command-line text.

        Returns
        -------
        Any
            The converted value.
        """
        try:
            if self.type is bool and isinstance(raw, str):
                if raw.lower() not in ("1", "0", "true", "false", "yes", "no"):
                    raise ValueError
                value = raw.lower() in ("1", "true", "yes")
            elif self.type in (list, tuple) and isinstance(raw, str):
                value = [int(v) if v.strip().lstrip("-").isdigit() else v.strip()
                         for v in raw.replace("[", "").replace("]", "").split(",") if v.strip()]
            else:
                value = self.type(raw)
        except (TypeError, ValueError):
            raise EstimatorError(f"option --{name.replace('_', '-')}: {raw!r} is not a valid "
                                 f"{self.type.__name__}") from None
        if self.choices is not None and value not in self.choices:
            raise EstimatorError(f"option --{name.replace('_', '-')}: {value!r} is not one of "
                                 f"{', '.join(map(str, self.choices))}")
        return value
