"""Changing a page's choices and what can be chosen, in one step.

A page declares each choice as a ``param`` selector shown by a widget made with ``from_param``.
When the page itself changes the options and the choice at once (a new session, new maps), Panel
would pass them to the widget one after the other, and a served ``Select`` (or ``CheckBoxGroup``,
``MultiChoice``) replaces a value missing from its new options by the first option (or drops it)
in between: watchers would see a choice nobody made and redraw or recompute for it.

:func:`set_choices` sets the parameters without events (``param.parameterized.discard_events``),
gives each widget its options and value in one update, then triggers the parameters together:
every watcher runs once, with the final values.
"""
from __future__ import annotations

from typing import Any

import param

__all__ = ["set_choices"]


def _widget_options(owner: param.Parameterized, name: str, widget: Any) -> Any:
    """The options Panel gives a ``from_param`` widget of ``owner.param[name]``."""
    options = owner.param[name].get_range()
    if isinstance(widget.param["options"], param.List):
        options = list(options)
    return options


def set_choices(owner: param.Parameterized, choices: dict[str, tuple[Any, Any, Any]], *,
                trigger: bool = True, **values: Any) -> None:
    """Set choice parameters of ``owner`` with their options, and plain parameters, at once.

    Parameters
    ----------
    owner
        The page.
    choices
        Parameter name -> ``(widget, objects, value)``: the ``from_param`` widget showing it, the
        selector's new objects (a list, or a dict label -> value) and the new value.
    trigger
        Trigger the parameters afterwards (every watcher runs once); ``False`` when the caller
        shows the new state itself.
    **values
        Other parameters of ``owner`` set (and triggered) with them, e.g. the data the choices
        are about.
    """
    with param.parameterized.discard_events(owner):
        for name, (_, objects, _) in choices.items():
            owner.param[name].objects = objects
        owner.param.update(**values, **{name: value for name, (_, _, value) in choices.items()})
    for name, (widget, _, value) in choices.items():
        widget.param.update(options=_widget_options(owner, name, widget), value=value)
    if trigger:
        owner.param.trigger(*choices, *values)
