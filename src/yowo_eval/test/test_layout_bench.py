"""The layout benchmark's table: a row per layout, '-' where a run gave no number."""

from yowo_eval.layout_bench import BEGIN, END, layouts_markdown


def test_a_row_per_layout_with_its_numbers_or_a_dash():
    cases = [
        {
            "layout": "yowo",
            "exit": 0,
            "registration_pos_avg_m": 0.117,
            "registration_rot_avg_deg": 3.19,
            "ego_ate_m": 0.0023,
            "ratio": 1.5,
        },
        {
            "layout": "zed",
            "exit": 1,
            "registration_pos_avg_m": None,
            "registration_rot_avg_deg": None,
            "ego_ate_m": None,
            "ratio": 2.0,
        },
    ]
    text = layouts_markdown(cases, "yowo bench-layouts --preset small")
    assert text.startswith(BEGIN) and text.rstrip().endswith(END)
    assert "| yowo | 0 | 0.1170 / 3.190 | 0.0023 | 1.50 |" in text
    assert "| zed | 1 | - | - | 2.00 |" in text and "yowo bench-layouts --preset small" in text
