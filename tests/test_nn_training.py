"""The training loop shared by the networks: its checks, time budget and Ctrl-C, on a toy step."""

import signal
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxocean.cli import main
from jaxocean.io import dataset
from jaxocean.nn import geometry as geo
from jaxocean.nn import geometry_train as gt
from jaxocean.nn.training import train_loop


def _toy(run_dir, *, on_step=None, **kwargs):
    """A loop whose state counts the steps taken and sums the batches it saw."""

    def step(state, batch, key):
        if on_step is not None:
            on_step(int(state["n"]))
        return {"n": state["n"] + 1, "total": state["total"] + batch}, {"loss": jnp.asarray(1.0)}

    settings = dict(state={"n": jnp.asarray(0), "total": jnp.zeros(1)}, step=step,
                    batches=lambda epoch: iter([jnp.asarray([float(epoch * 10 + b)]) for b in range(4)]),
                    validate=lambda state: {"loss": 1.0 / (1.0 + float(state["n"]))}, epochs=3, steps_per_epoch=4,
                    key=jax.random.key(0), signature={"toy": 1}, progress=False)
    settings.update(kwargs)
    return train_loop(run_dir, **settings)


@pytest.mark.parametrize("name, value", [("epochs", 0), ("steps_per_epoch", -1), ("patience", 0),
                                         ("checkpoint_every", 0), ("epochs", 2.5)])
def test_counts_below_one_are_refused(tmp_path, name, value):
    with pytest.raises(ValueError, match=f"{name} must be a positive integer"):
        _toy(tmp_path, **{name: value})
    assert not (tmp_path / "checkpoint.npz").exists()


@pytest.mark.parametrize("budget", [0.0, -1.0])
def test_a_budget_that_is_not_positive_is_refused(tmp_path, budget):
    with pytest.raises(ValueError, match="time budget must be a positive number"):
        _toy(tmp_path, time_budget_s=budget)


def test_the_time_budget_is_read_after_every_step(tmp_path):
    result = _toy(tmp_path, time_budget_s=0.3, epochs=5, on_step=lambda n: time.sleep(0.2))
    assert result["stopped"] == "time_budget"
    # the budget ran out inside the first epoch (4 steps of 0.2 s): that epoch validated and saved
    assert 1 <= result["steps"] < 4 and len(result["history"]) == 1


@pytest.mark.parametrize("stop", ["time_budget", "early_stopping"])
def test_running_a_stopped_run_again_changes_nothing(tmp_path, stop):
    settings = (dict(time_budget_s=0.3, on_step=lambda n: time.sleep(0.2)) if stop == "time_budget"
                else dict(patience=1, validate=lambda state: {"loss": 1.0}))  # no gain after the first epoch
    first = _toy(tmp_path, epochs=5, **settings)
    assert first["stopped"] == stop
    before = (tmp_path / "checkpoint.npz").read_bytes()
    again = _toy(tmp_path, epochs=5, **settings)  # took one more epoch (or step) each time before
    assert again["stopped"] == stop and again["steps"] == first["steps"] and len(again["history"]) == len(
        first["history"])
    assert (tmp_path / "checkpoint.npz").read_bytes() == before


def test_a_resume_with_other_settings_names_what_changed(tmp_path):
    from jaxocean.nn import CheckpointError

    _toy(tmp_path, signature={"config": {"epochs": 2, "lr": 0.1}, "dataset": "a"}, checkpoint_every=1,
         stop_after_steps=1)
    with pytest.raises(CheckpointError, match=r"other settings \(config\.epochs: 2 -> 3; dataset: \"a\" -> \"b\"\)"):
        _toy(tmp_path, signature={"config": {"epochs": 3, "lr": 0.1}, "dataset": "b"})


def test_a_run_directory_of_another_network_is_refused_in_one_line(tmp_path):
    # `train-geometry` given a `train-waves` run directory listed the settings that differ
    # (every one of the other network's) instead of saying the directory is another's
    from jaxocean.nn import CheckpointError

    _toy(tmp_path, signature={"config": {"epochs": 2}}, checkpoint_every=1, stop_after_steps=1, network="waves")
    with pytest.raises(CheckpointError, match=r"checkpoint\.npz: belongs to the training of a waves network, not of "
                                              r"a geometry network; use a new --out directory$"):
        _toy(tmp_path, signature={"config": {"crop": 64}}, network="geometry")
    # the same network resumes
    assert _toy(tmp_path, signature={"config": {"epochs": 2}}, network="waves")["steps"] == 12


def test_ctrl_c_keeps_the_step_in_progress_and_resumes_to_the_same_end(tmp_path):
    full = _toy(tmp_path / "full")

    def interrupt(n):
        if n == 5:
            signal.raise_signal(signal.SIGINT)  # as a Ctrl-C during step 6

    before = signal.getsignal(signal.SIGINT)  # Python's default, or SIG_IGN in a background job
    with pytest.raises(KeyboardInterrupt):
        _toy(tmp_path / "cut", on_step=interrupt)
    assert signal.getsignal(signal.SIGINT) is before  # the handler is put back
    resumed = _toy(tmp_path / "cut")
    assert full["steps"] == resumed["steps"] == 12
    for a, b in zip(jax.tree.leaves(full["state"]), jax.tree.leaves(resumed["state"])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_run_killed_after_its_last_epoch_keeps_that_epoch_in_its_history(tmp_path, monkeypatch):
    import json

    from jaxocean.nn import training

    write_json = training.write_json

    def killed_at_the_last_epoch(path, history):
        if len(history) == 3:
            raise KeyboardInterrupt  # as a kill between the epoch's checkpoint and its history
        write_json(path, history)

    monkeypatch.setattr(training, "write_json", killed_at_the_last_epoch)
    with pytest.raises(KeyboardInterrupt):
        _toy(tmp_path)
    monkeypatch.setattr(training, "write_json", write_json)
    again = _toy(tmp_path)
    assert len(again["history"]) == 3
    assert json.loads((tmp_path / "history.json").read_text()) == again["history"]


def test_a_crop_longer_than_one_side_takes_that_whole_side():
    frames = jnp.arange(8 * 24, dtype=jnp.float32).reshape(1, 8, 24, 1)
    (window,) = gt._crop(jax.random.key(0), [frames], 16, 8, 24)  # a gather out of range before
    assert window.shape == (1, 8, 16, 1)
    x0 = int(window[0, 0, 0, 0])
    np.testing.assert_array_equal(window, frames[:, :, x0:x0 + 16])


@pytest.mark.slow  # several training runs started
def test_datasets_too_small_to_train_on_say_what_they_lack(tmp_path):
    config = gt.TrainConfig(model=geo.GeometryConfig(widths=(4, 8), roughness_widths=(4, 8)), losses="image+gan",
                            epochs=1, steps_per_epoch=1, batch_size=1, crop=8, val_frames=1,
                            time_budget_minutes=None)
    dataset.simulate(tmp_path / "ds7", 7, 1, (8, 8), seed=0, progress=False)
    with pytest.raises(ValueError, match="'gan' loss needs at least 2 frames per scene.*has 1"):
        gt.train(tmp_path / "ds7", tmp_path / "run", config, progress=False)
    # seven 1-frame scenes leave five training frames: no batch of 8 (it trained 0 steps before)
    with pytest.raises(ValueError, match=r"ds7: the train split \(5 frames\) must hold a batch \(8\)"):
        gt.train(tmp_path / "ds7", tmp_path / "run", config._replace(losses="supervised", batch_size=8),
                 progress=False)
    # three scenes: no validation split (it validated nothing and wrote no model)
    dataset.simulate(tmp_path / "ds3", 3, 2, (8, 8), seed=0, progress=False)
    with pytest.raises(ValueError, match="has 3 and 0 \\(simulate at least 7 scenes\\)"):
        gt.train(tmp_path / "ds3", tmp_path / "run", config._replace(losses="supervised"), progress=False)


def test_a_wave_train_split_too_small_for_a_batch_names_the_scenes_needed(tmp_path):
    from jaxocean.nn import waves as wn
    from jaxocean.nn import waves_train as wt

    # seven scenes leave five to train on; a wave batch item is a scene, so more frames do not help
    dataset.simulate(tmp_path / "ds7", 7, 2, (8, 8), seed=0, progress=False)
    config = wt.TrainConfig(model=wn.WaveNetConfig(frames=2, slots=2, widths=(4, 8), hidden=8), epochs=1,
                            steps_per_epoch=1, batch_size=8, time_budget_minutes=None)
    with pytest.raises(ValueError, match=r"the train split \(5 scenes\) must hold a batch \(8\); simulate at least "
                                         r"10 scenes, or"):
        wt.train(tmp_path / "ds7", tmp_path / "run", config, progress=False)
    assert len(dataset.split_scenes(10, 0)["train"]) == 8 and len(dataset.split_scenes(9, 0)["train"]) == 7


@pytest.mark.parametrize("command, option", [("train-geometry", "--epochs=0"), ("train-geometry", "--steps-per-epoch=-1"),
                                             ("train-geometry", "--time-budget-min=0"),
                                             ("train-waves", "--epochs=0"), ("train-waves", "--time-budget-min=-2"),
                                             ("eval-geometry", "--max-frames=-1")])
def test_the_commands_refuse_counts_below_one(tmp_path, capsys, command, option):
    with pytest.raises(SystemExit) as exit_info:
        main([command, str(tmp_path), option] + (["--out", str(tmp_path / "run")] if command != "eval-geometry" else []))
    assert exit_info.value.code == 2
    assert "expected a positive" in capsys.readouterr().err


def test_loading_the_shipped_models_compiles_nothing(compilations):
    # the parameter structure a checkpoint fills is evaluated abstractly: drawing it with the
    # initialisers compiled one program per parameter shape (7.8 s for the geometry model on
    # 2 cores) whose values were then replaced by the file's
    from jaxocean.nn import waves as wave_net

    jax.clear_caches()  # nothing compiled by an earlier test may hide a compilation here
    with compilations() as compiled:
        geometry_model, wave_model = geo.load(), wave_net.load()
    assert compiled == []
    # and the files' values were read: finite, and not the initialisers' zero biases alone
    for model in (geometry_model, wave_model):
        leaves = jax.tree.leaves(model.params)
        assert all(np.all(np.isfinite(leaf)) for leaf in leaves)
        assert sum(float(np.abs(leaf).sum()) for leaf in leaves) > 0
