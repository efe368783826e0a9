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


def test_the_camera_without_camera_info_gets_its_focal_error_and_ratio_row():
    case = {
        "layout": "realsense, cam00 without CameraInfo",
        "exit": 0,
        "registration_pos_avg_m": 0.011,
        "registration_rot_avg_deg": 0.27,
        "ego_ate_m": 0.0016,
        "ratio": 1.5,
        "estimated": {
            "camera": "cam00",
            "status": "ok",
            "focal_px": 330.76,
            "focal_true_px": 330.0,
            "focal_error": 330.76 / 330.0 - 1,
            "focal_sigma_px": 3.09,
            "k1_k2": [-0.162, 0.041],
            "k1_k2_true": [-0.1497, 0.0343],
            "pos_m": 0.0171,
            "rot_deg": 0.642,
            "others_pos_avg_m": 0.0091,
        },
    }
    failed = {"camera": "cam04", "status": "failed", "reason": "in no group"}
    others = [{**case, "layout": "zed", "estimated": {"camera": "cam01"}}, {**case, "estimated": failed}]
    text = layouts_markdown([case, *others], "yowo bench-layouts")
    row = "| cam00 | ok | 330.8 / 330.0 | +0.23 % | 3.09 | -0.162, 0.041 / -0.150, 0.034 | 0.0171 / 0.642 | 0.0091 | 1.88 |"
    assert row in text, text
    assert "| cam01 |" not in text  # a run that gave no numbers has no row
    assert "| cam04 | failed: in no group | - |" in text  # a camera left unregistered says why
