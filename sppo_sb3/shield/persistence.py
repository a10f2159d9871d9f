"""Loading a shielded model: the saved rule is rebuilt, passed in, or dropped explicitly — never lost silently.

SB3 saves every attribute of a model, the shield's ``shield`` argument and the rule in use ``shield_rule``
included, with cloudpickle. A rule whose class lives in a module that is not importable where the model is loaded
cannot be rebuilt; SB3's ``load`` would then fail deep inside unpickling (or drop the attribute with a warning). The
:class:`ShieldedLoadMixin` rebuilds the rule first and, where that fails, raises :class:`ShieldRuleLoadError`, which
says how to pass the rule (``custom_objects={"shield_rule": rule}``) or to load the model unshielded on purpose
(``custom_objects={"shield": None}``).
"""

from __future__ import annotations

import base64
import io
import json
import pathlib
import zipfile
from typing import Any, TypeVar

import cloudpickle
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.save_util import open_path
from stable_baselines3.common.type_aliases import GymEnv

from sppo_sb3.shield.base import ShieldingRule

SHIELD_KEYS = ("shield_rule", "shield")
SelfShielded = TypeVar("SelfShielded", bound="ShieldedLoadMixin")


class ShieldRuleLoadError(RuntimeError):
    """The shielding rule saved with a model cannot be rebuilt where the model is loaded."""


def read_saved_data(path: str | pathlib.Path | io.BufferedIOBase) -> dict[str, Any]:
    """The JSON ``data`` entry of an SB3 save file, nothing deserialised; ``{}`` where it cannot be read (SB3 says why).

    :param path: the save file, as SB3's ``load`` accepts it; a file object is left at the position it had.
    """
    try:
        file = open_path(path, "r", verbose=0, suffix="zip")
    except (OSError, ValueError):
        return {}
    start = file.tell()
    try:
        with zipfile.ZipFile(file) as archive:
            data = json.loads(archive.read("data").decode())
    except (zipfile.BadZipFile, KeyError, ValueError, OSError):
        data = {}
    finally:
        if file is path:
            file.seek(start)
        else:
            file.close()
    return data if isinstance(data, dict) else {}


def shield_custom_objects(custom_objects: dict[str, Any] | None) -> dict[str, Any]:
    """``custom_objects`` with the shield's two entries made consistent.

    ``{"shield_rule": rule}`` (or ``{"shield": rule}``) loads the model shielded by ``rule``; ``{"shield": None}``
    loads it unshielded. ``{"shield_rule": None}`` alone is rejected: dropping the shield must be said with
    ``"shield": None``.

    :param custom_objects: the ``custom_objects`` given to ``load``.
    """
    objects = dict(custom_objects or {})
    for key in SHIELD_KEYS:
        value = objects.get(key)
        if value is not None and not isinstance(value, (ShieldingRule, str)):
            raise TypeError(f"custom_objects[{key!r}] must be a sppo_sb3.shield.ShieldingRule or None, got {value!r}.")
    if isinstance(objects.get("shield"), ShieldingRule):
        objects.setdefault("shield_rule", objects["shield"])
    if isinstance(objects.get("shield_rule"), ShieldingRule):
        objects.setdefault("shield", objects["shield_rule"])
    if "shield" in objects and objects["shield"] is None:
        objects["shield_rule"] = None
    if "shield_rule" in objects and objects["shield_rule"] is None and objects.get("shield", "saved") is not None:
        raise ValueError(
            "custom_objects={'shield_rule': None} would load the model without its shield. To do that on purpose, "
            "pass custom_objects={'shield': None}; to keep it shielded, pass the rule: {'shield_rule': YourRule()}."
        )
    return objects


def rebuild_saved_shield(path: Any, custom_objects: dict[str, Any], algorithm: str) -> dict[str, Any]:
    """Rebuild the saved ``shield_rule`` and ``shield`` that ``custom_objects`` does not replace.

    :param path: the save file.
    :param custom_objects: the consistent ``custom_objects`` (:func:`shield_custom_objects`).
    :param algorithm: the class name, for the error message.
    :return: ``custom_objects`` with the rebuilt entries added, so that SB3 does not unpickle them again.
    :raises ShieldRuleLoadError: when a saved entry cannot be rebuilt.
    """
    data = read_saved_data(path)
    objects = dict(custom_objects)
    for key in SHIELD_KEYS:
        item = data.get(key)
        if key in objects or not (isinstance(item, dict) and ":serialized:" in item):
            continue
        try:
            objects[key] = cloudpickle.loads(base64.b64decode(item[":serialized:"].encode()))
        except Exception as error:
            raise ShieldRuleLoadError(
                f"The shielding rule saved with this model cannot be rebuilt ({type(error).__name__}: {error}): its "
                "class must be importable from the module it was defined in when the model was saved. Keep the model "
                f"shielded by passing the rule: {algorithm}.load(path, custom_objects={{'shield_rule': YourRule()}}); "
                f"or load it unshielded, on purpose: {algorithm}.load(path, custom_objects={{'shield': None}})."
            ) from error
    return objects


class ShieldedLoadMixin:
    """``load`` for shielded algorithms: the saved rule is rebuilt, passed in ``custom_objects``, or dropped with
    ``shield=None`` (in ``custom_objects`` or as a keyword) — see the module docstring."""

    @classmethod
    def load(
        cls: type[SelfShielded],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfShielded:
        """SB3's ``load``; ``custom_objects={"shield_rule": rule}`` keeps a model whose rule cannot be rebuilt
        shielded, ``custom_objects={"shield": None}`` (or ``shield=None``) loads it unshielded.

        :raises ShieldRuleLoadError: when the saved rule cannot be rebuilt and none is passed.
        """
        objects = {**(custom_objects or {}), **{key: kwargs.pop(key) for key in SHIELD_KEYS if key in kwargs}}
        objects = rebuild_saved_shield(path, shield_custom_objects(objects), cls.__name__)
        load = super().load  # type: ignore[misc]
        model = load(path, env, device, objects, print_system_info, force_reset, **kwargs)
        assert isinstance(model, BaseAlgorithm)
        return model  # type: ignore[return-value]
