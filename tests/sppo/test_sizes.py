"""SPPO's named sizes: the class trains at CPU sizes by default, TD-MPC's on request, explicit arguments win."""

from __future__ import annotations

import pytest

from sppo_sb3 import SPPO
from sppo_sb3.sppo.sizes import SIZES


def sizes_of(model: SPPO) -> tuple[int, ...]:
    told, plan = model.policy_kwargs, model.planner_config
    return (told["latent_dim"], told["encoder_dim"], told["hidden_dim"], plan.num_samples, plan.num_elites,
            plan.iterations, model.batch_size, model.horizon, plan.horizon)  # fmt: skip


def test_the_class_defaults_are_cpu_sizes_and_tdmpc_is_named() -> None:
    assert sizes_of(SPPO("TOLDPolicy", "SafePointCircle-v0", compile=False)) == (32, 64, 128, 64, 8, 3, 128, 3, 3)
    model = SPPO("TOLDPolicy", "SafePointCircle-v0", sizes="tdmpc", compile=False)
    assert sizes_of(model) == (50, 256, 512, 512, 64, 6, 512, 5, 5)
    assert model.policy.model.encoder[0].out_features == 256  # the networks are built at those sizes


def test_explicit_arguments_override_the_named_sizes() -> None:
    model = SPPO(
        "TOLDPolicy",
        "SafePointCircle-v0",
        sizes="tdmpc",
        policy_kwargs=dict(hidden_dim=64),
        planner_kwargs=dict(num_samples=128),
        batch_size=16,
        horizon=4,
        compile=False,
    )
    assert sizes_of(model) == (50, 256, 64, 128, 64, 6, 16, 4, 4)


def test_sizes_survive_save_and_load_and_are_logged(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    model = SPPO(
        "TOLDPolicy", "SafePointCircle-v0", sizes="tdmpc", policy_kwargs=dict(hidden_dim=64), verbose=1, compile=False
    )
    assert "SPPO sizes ('tdmpc' and overrides): TOLD latent 50, encoder 256, hidden 64" in capsys.readouterr().out
    model.save(tmp_path / "model")
    loaded = SPPO.load(tmp_path / "model")
    assert loaded.sizes == "tdmpc" and sizes_of(loaded) == sizes_of(model)


def test_an_unknown_name_says_which_exist() -> None:
    with pytest.raises(ValueError, match="'cpu', 'tdmpc'"):
        SPPO("TOLDPolicy", "SafePointCircle-v0", sizes="gpu")  # type: ignore[arg-type]
    assert set(SIZES) == {"cpu", "tdmpc"}
