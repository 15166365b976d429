"""Per-agent traced hyper-parameters (issue 33): every agent names its HParams class; a grid, --hp and --help take
that class's fields and nothing else; range checks live with the fields they check."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from test_engine import TINY

from proto_brax.agents import registry
from proto_brax.agents.iql import IQLHParams
from proto_brax.agents.pex import PEXHParams
from proto_brax.agents.sac import SACHParams
from proto_brax.agents.td3 import TD3HParams
from proto_brax.cli.sweep import parse_args
from proto_brax.config import HParams, validate_hparams
from proto_brax.train.grid import make_grid
from proto_brax.train.online import make_finetune


def test_every_agent_names_its_hparams_and_the_temperature_agents_carry_sacs():
    for name in registry.AGENTS:
        algo = registry.agent(name)
        assert issubclass(algo.hparams, HParams), name
        assert algo.temperature == issubclass(algo.hparams, SACHParams), name  # init_learner reads alpha_sac_init
    assert registry.agent("td3").hparams is TD3HParams and registry.agent("pex").hparams is PEXHParams
    assert set(PEXHParams.names()) == set(IQLHParams.names()) | {"pex_inv_temperature"}
    # the shared class holds no agent's own field
    assert not {"beta", "expectile", "cql_alpha", "alpha_sac_init", "off2on_temperature"} & set(HParams.names())


def test_a_grid_takes_the_agents_fields_only_and_names_the_class():
    grid = make_grid({"beta": [2.5, 4.0]}, [0], hparams=TD3HParams)
    assert isinstance(grid.hparams, TD3HParams)
    np.testing.assert_array_equal(np.asarray(grid.hparams.beta), [2.5, 4.0])
    np.testing.assert_array_equal(np.asarray(grid.hparams.expl_noise), np.float32([0.1, 0.1]))  # the class's default
    with pytest.raises(ValueError, match=r"Unknown hyper-parameter\(s\) \['beta'\] of SACHParams"):
        make_grid({"beta": [4.0]}, [0], hparams=SACHParams)
    with pytest.raises(ValueError, match=r"Unknown hyper-parameter\(s\) \['expectile'\] of TD3HParams"):
        TD3HParams.create(expectile=0.7)


def test_range_checks_follow_the_class():
    with pytest.raises(ValueError, match="expectile must lie in"):
        validate_hparams(IQLHParams.create(expectile=1.0))
    with pytest.raises(ValueError, match="alpha_sac_init must be > 0"):
        validate_hparams(SACHParams.create(alpha_sac_init=0.0))
    with pytest.raises(ValueError, match="tau must lie in"):  # the shared checks still run for a subclass
        validate_hparams(TD3HParams.create(tau=1.5))
    validate_hparams(TD3HParams.create(beta=2.5))


def test_a_finetune_refuses_another_agents_hparams_before_tracing_its_update():
    ft = make_finetune(dataclasses.replace(TINY, algo="td3"))
    assert ft.hparams is TD3HParams
    with pytest.raises(TypeError, match="algo 'td3' takes TD3HParams, got SACHParams"):
        ft.init(SACHParams.create(), jax.random.PRNGKey(0), None, None)


def test_the_sweep_help_lists_the_methods_own_hyper_parameters(capsys):
    with pytest.raises(SystemExit):
        parse_args(["--algo", "proto-td3", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "TD3HParams" in text and "beta 4" in text and "expl_noise 0.1" in text
    assert "alpha_sac_init" not in text  # TD3 has no entropy temperature
    with pytest.raises(SystemExit):
        parse_args(["--algo", "sac-scratch", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "SACHParams" in text and "alpha_sac_init 1," in text  # the method's own value (SAC from scratch)


def test_a_sweep_refuses_a_hyper_parameter_its_agent_lacks(tmp_path):
    from proto_brax.experiment.plan import plan_sweep
    from proto_brax.sweep import sweep_args

    args = sweep_args("proto-sac", preset="smoke", hp={"expectile": 0.8}, out=tmp_path / "o")
    with pytest.raises(ValueError, match=r"\['expectile'\] of SACHParams"):
        plan_sweep(args)
    assert not (tmp_path / "o").exists()
