"""`vecu figures --quick`: every seed figure of issue 18 is written as a non-trivial PNG."""

from __future__ import annotations

from vecu.cli import main

EXPECTED = {
    "throttle_fig2_model_error.png", "throttle_fig3_position_estimate.png",
    "speed_fig5_sensitivity.png", "speed_fig8_spectrum_raw.png", "speed_fig11_spectrum_est.png",
    "steering_fig2_sideslip.png", "steering_fig3_steering_angle.png",
    "manifold_fig4_cac_ise_histogram.png", "manifold_fig5_cac_iae_histogram.png",
}


def test_every_seed_figure_is_a_png(tmp_path, capsys) -> None:
    assert main(["figures", "--quick", "--out", str(tmp_path)]) == 0
    written = {p.name: p for p in tmp_path.glob("*.png")}
    assert set(written) == EXPECTED
    for p in written.values():
        data = p.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 15_000, p.name
    assert "peak 2.41 dB" in capsys.readouterr().out


def test_figures_out_must_be_a_directory(tmp_path, capsys) -> None:
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["figures", "--out", str(f), "--only", "speed"]) == 2
    assert "not a directory" in capsys.readouterr().err
