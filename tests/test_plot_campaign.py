"""scripts/plot_campaign.py: the campaign's measured files drawn against its CPU-hours."""

import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CSV = REPO / "docs" / "figures" / "campaign6_evaluations.csv"


def _script():
    spec = importlib.util.spec_from_file_location("plot_campaign", REPO / "scripts" / "plot_campaign.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_committed_measures_are_read_in_campaign_order_and_drawn(tmp_path):
    script = _script()
    rows = script.read_rows(CSV)
    hours = [r["campaign_cpu_h"] for r in rows]
    assert hours == sorted(hours)
    # every file of the fine-tune was measured on a stage that started after the base (4.6 CPU-h)
    assert min(hours) > 4.6
    # one shipped file, better than standing still on the 16 scenes
    shipped = [r for r in rows if "shipped" in r["file"]]
    assert len(shipped) == 1 and shipped[0]["position_error_m"] < script.STANDING_STILL_M
    out = tmp_path / "c.png"
    assert script.main([str(CSV), str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_field_that_is_not_a_number_is_named_with_its_line(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    lines = CSV.read_text().splitlines()
    bad.write_text("\n".join([lines[0], lines[1].replace("19.76", "n/a")]) + "\n")
    assert _script().main([str(bad), str(tmp_path / "c.png")]) == 2
    err = capsys.readouterr().err
    assert "bad.csv, line 2" in err and "'position_error_m'" in err and "n/a" in err


def test_a_missing_column_is_named(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("file,finetune_step\nx,1\n")
    assert _script().main([str(bad), str(tmp_path / "c.png")]) == 2
    assert "the column 'campaign_cpu_h' is missing" in capsys.readouterr().err
