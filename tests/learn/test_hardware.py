"""The host's figures for the model cards: the latency timer and the hardware description."""

import pytest
import torch

from edge_explorer.learn.hardware import hardware_description, torch_latency_ms


def test_the_latency_timer_warms_up_times_each_repeat_and_restores_the_thread_count():
    calls = []
    before = torch.get_num_threads()
    figures = torch_latency_ms(lambda: calls.append(torch.get_num_threads()), repeats=7, threads=1)
    assert len(calls) == 7 + 5  # five warm-up calls are run but not timed
    assert set(calls) == {1}
    assert torch.get_num_threads() == before
    assert figures["threads"] == 1 and figures["repeats"] == 7
    assert 0 <= figures["median_ms"] <= figures["p90_ms"]


def test_the_thread_count_is_restored_when_the_network_raises():
    before = torch.get_num_threads()

    def fails():
        raise RuntimeError("bad input")

    with pytest.raises(RuntimeError, match="bad input"):
        torch_latency_ms(fails, repeats=1, threads=1)
    assert torch.get_num_threads() == before


def test_a_cpu_stretch_names_its_threads_and_precision():
    text = hardware_description("cpu", loader_workers=0, threads=2, bfloat16=True)
    assert "CPU only, 2 torch thread(s), bfloat16 autocast" in text
    assert "loader workers" not in text
