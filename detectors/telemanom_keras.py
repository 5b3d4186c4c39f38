"""Telemanom's forecaster in Keras 3 on TensorFlow: the paper's own stack, as an optional backend.

``Telemanom(backend="tensorflow")`` trains and runs its LSTM forecaster here instead of in torch.
The model and its training follow the original implementation (khundman/telemanom,
``telemanom/modeling.py``): stacked ``LSTM`` layers, each followed by ``Dropout``, a ``Dense``
layer of ``n_predictions`` outputs per forecast channel, the Adam optimiser on the mean squared
error, and ``EarlyStopping`` on the validation loss with ``patience`` and ``min_delta``. Keras'
own defaults (Glorot / orthogonal initialisation, unit forget bias) apply, as they did there.

The training data, the validation windows (the last ``validation_split`` of the training
windows, as ``model.fit(validation_split=...)`` takes them) and the options shared with the torch
backend (``residual``, ``per_channel``, ``max_train_windows``) are the detector's, so the two
backends differ only in the framework, its initialisation and its arithmetic. Like the torch
backend, the best validation weights are restored after early stopping
(``restore_best_weights=True``; the published code kept the last ones).

Determinism: each model is seeded with ``keras.utils.set_random_seed`` (from the detector's
``random_state``) under ``tf.config.experimental.enable_op_determinism()``, so the same seed gives
the same weights and scores. Python's and numpy's global random states, which
``set_random_seed`` reseeds, are restored afterwards (op determinism, a process-wide switch that
TensorFlow offers only to turn on, stays on). The fitted weights are kept as numpy arrays, so a
fitted detector pickles without TensorFlow objects; TensorFlow is imported only when this
backend is used.
"""

from __future__ import annotations

import contextlib
import os
import random
import sys
from collections.abc import Iterator, Sequence

import numpy as np
import torch

from scart_bench.detectors.base import DetectorError

#: What to tell a user without TensorFlow.
INSTALL_HINT = "telemanom backend 'tensorflow' needs tensorflow-cpu: pip install 'scart-bench[tensorflow]'"
#: Windows per batch when computing the validation loss (as the torch backend).
_VAL_BATCH = 1024


def import_tensorflow():
    """``(tensorflow, keras)``, imported on first use; a :class:`DetectorError` when absent.

    Keras 3 runs on the backend named by ``KERAS_BACKEND``; when Keras is not imported yet, it is
    set to "tensorflow" for this process (another backend would not be the paper's stack).
    """
    if "keras" not in sys.modules:
        os.environ["KERAS_BACKEND"] = "tensorflow"
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")  # no start-up chatter from TensorFlow
    try:
        import keras
        import tensorflow as tf
    except ImportError as exc:
        raise DetectorError(INSTALL_HINT) from exc
    if keras.backend.backend() != "tensorflow":
        raise DetectorError(
            f"telemanom backend 'tensorflow': Keras already runs on {keras.backend.backend()!r} in this "
            "process (KERAS_BACKEND); start it with KERAS_BACKEND=tensorflow"
        )
    return tf, keras


@contextlib.contextmanager
def _seeded(tf, keras, seed: int) -> Iterator[None]:
    """Keras seeded with ``seed`` and TensorFlow ops deterministic, global RNG states kept.

    Op determinism is a process-wide switch that TensorFlow only exposes to turn on: it stays on.
    """
    tf.config.experimental.enable_op_determinism()
    with _rng_kept():
        keras.utils.set_random_seed(int(seed))
        yield


@contextlib.contextmanager
def _rng_kept() -> Iterator[None]:
    """Python's and numpy's global random states unchanged by what runs inside (Keras draws
    default seeds for new layers from Python's ``random``)."""
    py_state, np_state = random.getstate(), np.random.get_state()
    try:
        yield
    finally:
        random.setstate(py_state)
        np.random.set_state(np_state)


def build_model(
    keras,
    l_s: int,
    n_inputs: int,
    n_outputs: int,
    hidden: Sequence[int],
    dropout: float,
    n_predictions: int,
    skip: Sequence[int] | None = None,
):
    """The published model: ``LSTM -> Dropout`` per layer (all but the last return sequences),
    ``Dense(n_outputs * n_predictions)``, reshaped to (batch, n_predictions, n_outputs).

    With ``skip`` (the input positions of the outputs) the last observed values are added to the
    forecasts, as the torch backend's ``residual`` option.
    """
    x = keras.Input(shape=(int(l_s), int(n_inputs)), dtype="float32")
    h = x
    sizes = [int(u) for u in hidden]
    for i, units in enumerate(sizes):
        h = keras.layers.LSTM(units, return_sequences=i < len(sizes) - 1)(h)
        h = keras.layers.Dropout(float(dropout))(h)
    out = keras.layers.Dense(int(n_outputs) * int(n_predictions))(h)
    out = keras.layers.Reshape((int(n_predictions), int(n_outputs)))(out)
    if skip is not None:
        last = keras.ops.take(x[:, -1, :], np.asarray(skip, dtype=np.int32), axis=1)
        out = out + keras.ops.expand_dims(last, 1)
    return keras.Model(x, out)


def _windows_dataset(keras):
    """A ``keras.utils.PyDataset`` of (history, targets) windows cut from one flat array."""

    class Windows(keras.utils.PyDataset):
        def __init__(self, data, target, starts, l_s, n_pred, batch_size, seed=None):
            super().__init__(workers=1, use_multiprocessing=False)
            self.data, self.target, self.starts = data, target, np.asarray(starts, dtype=np.int64)
            self.steps_in = np.arange(int(l_s))
            self.steps_out = np.arange(int(l_s), int(l_s) + int(n_pred))
            self.batch_size = int(batch_size)
            self.rng = np.random.default_rng(seed) if seed is not None else None
            self.order = self._order()

        def _order(self) -> np.ndarray:
            if self.rng is None:
                return self.starts
            return self.starts[self.rng.permutation(len(self.starts))]

        def __len__(self) -> int:
            return -(-len(self.starts) // self.batch_size)

        def __getitem__(self, i):
            idx = self.order[i * self.batch_size : (i + 1) * self.batch_size]
            return self.data[idx[:, None] + self.steps_in], self.target[idx[:, None] + self.steps_out]

        def on_epoch_end(self) -> None:
            self.order = self._order()  # reshuffled every epoch (training windows only)

    return Windows


def train(
    flat: np.ndarray,
    glob: np.ndarray,
    inputs: np.ndarray,
    outputs: np.ndarray,
    seed: int,
    *,
    l_s: int,
    n_predictions: int,
    hidden: Sequence[int],
    dropout: float,
    epochs: int,
    batch_size: int,
    lr: float,
    patience: int,
    min_delta: float,
    validation_split: float,
    skip: Sequence[int] | None,
) -> tuple[list[np.ndarray], int]:
    """Train one forecaster on the windows starting at ``glob`` in ``flat`` (padded flights, float32).

    Returns the weights (numpy arrays, ``model.get_weights()`` order) and the epochs run.
    """
    tf, keras = import_tensorflow()
    data = np.ascontiguousarray(flat[:, inputs], dtype=np.float32)
    target = np.ascontiguousarray(flat[:, outputs], dtype=np.float32)
    n_val = int(round(len(glob) * float(validation_split)))
    n_val = min(n_val, len(glob) - 1)
    n_train = len(glob) - n_val
    Windows = _windows_dataset(keras)
    with _seeded(tf, keras, seed):
        model = build_model(keras, l_s, len(inputs), len(outputs), hidden, dropout, n_predictions, skip)
        model.compile(optimizer=keras.optimizers.Adam(learning_rate=float(lr)), loss="mse", jit_compile=False)
        train_windows = Windows(data, target, glob[:n_train], l_s, n_predictions, batch_size, seed=seed)
        fit_kw = {}
        if n_val > 0:
            fit_kw["validation_data"] = Windows(data, target, glob[n_train:], l_s, n_predictions, _VAL_BATCH)
            fit_kw["callbacks"] = [
                keras.callbacks.EarlyStopping(
                    monitor="val_loss",
                    patience=int(patience),
                    min_delta=float(min_delta),
                    restore_best_weights=True,
                )
            ]
        history = model.fit(train_windows, epochs=int(epochs), verbose=0, shuffle=False, **fit_kw)
        weights = [np.array(w, copy=True) for w in model.get_weights()]
    return weights, len(history.history["loss"])


class KerasForecaster:
    """A trained Keras forecaster called like the torch one: a (batch, l_s, inputs) tensor in,
    (batch, n_predictions, outputs) forecasts out (a torch tensor, float32, on the CPU)."""

    def __init__(self, model, tf):
        self.model = model
        spec = tf.TensorSpec(shape=(None, *model.input_shape[1:]), dtype=tf.float32)
        self._forward = tf.function(lambda x: model(x, training=False), input_signature=[spec])

    def __call__(self, xb: torch.Tensor) -> torch.Tensor:
        x = np.ascontiguousarray(xb.detach().cpu().numpy(), dtype=np.float32)
        return torch.from_numpy(np.array(self._forward(x)))  # a writable copy


def load(
    weights: list[np.ndarray],
    *,
    l_s: int,
    n_inputs: int,
    n_outputs: int,
    hidden: Sequence[int],
    dropout: float,
    n_predictions: int,
    skip: Sequence[int] | None,
) -> KerasForecaster:
    """A trained forecaster rebuilt from its weights (as :func:`train` returns them)."""
    tf, keras = import_tensorflow()
    with _rng_kept():
        model = build_model(keras, l_s, n_inputs, n_outputs, hidden, dropout, n_predictions, skip)
    model.set_weights(weights)
    return KerasForecaster(model, tf)
