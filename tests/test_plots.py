import numpy as np

from jaxocean import plots


def test_normal_and_roughness_maps():
    n = np.zeros((2, 2, 3), np.float32)
    n[..., 2] = 1.0
    rgb = plots.normal_to_rgb(n, mask=np.array([[True, False], [True, True]]))
    np.testing.assert_array_equal(rgb[0, 0], [128, 128, 255])
    np.testing.assert_array_equal(rgb[0, 1], [0, 0, 0])  # sky is black
    r = plots.roughness_to_rgb(np.array([[1e-5, 1e-3, 1e-1]]))
    brightness = r.astype(int).sum(-1)[0]
    assert brightness[0] < brightness[1] < brightness[2]  # magma: brighter for rougher


def test_contact_sheet_is_written_atomically(tmp_path):
    path = plots.contact_sheet(tmp_path / "sheet.png", [[np.zeros((4, 4, 3)), np.ones((4, 4, 3))]],
                               col_titles=["a", "b"], row_titles=["r"], title="t")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["sheet.png"]


def test_cell_titles_name_single_images_in_place_of_their_column_title(tmp_path, monkeypatch):
    seen = []
    save = plots.save_figure
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: seen.extend(ax.get_title() for ax in fig.axes)
                        or save(fig, path))
    img = np.zeros((4, 4, 3))
    plots.contact_sheet(tmp_path / "sheet.png", [[img, img], [img, img]], col_titles=["a", "b"],
                        cell_titles=[None, ["c", None]])
    assert seen == ["a", "b", "c", ""]


def test_nan_pixels_are_drawn_black_like_masked_ones():
    # a NaN went through the uint8 cast (undefined, with a RuntimeWarning), and a normal with
    # one NaN channel showed as a colour of its own instead of the masked pixels' black
    import warnings

    normal = np.zeros((1, 3, 3), np.float32)
    normal[..., 2] = 1.0
    normal[0, 1, 0] = np.nan  # one channel
    normal[0, 2] = np.nan  # all of them
    linear = np.full((1, 3, 3), 0.5, np.float32)
    linear[0, 1, 1] = np.nan
    linear[0, 2] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rgbs = [plots.normal_to_rgb(normal), plots.display(linear),
                plots.log_to_rgb(np.array([[1e-3, np.nan, np.nan]]))]
    for rgb in rgbs:
        assert rgb[0, 0].sum() > 0
        np.testing.assert_array_equal(rgb[0, 1:], 0)


def test_polar_charts_leave_room_past_the_outermost_wave(tmp_path, monkeypatch):
    # the demo's wave chart (radius omega) and the report's sea figure (radius period) put the
    # outermost wave exactly on matplotlib's rim, its marker half clipped
    from types import SimpleNamespace

    import jaxocean as jo
    from jaxocean import demo, report

    figures = []
    save = plots.save_figure
    monkeypatch.setattr(plots, "save_figure",
                        lambda fig, path, dpi=100: (figures.append(fig), save(fig, path, dpi))[1])
    waves = jo.make_waves([0.05, 0.03, 0.02], [2.0, 2.5, 3.0], [0.3, 1.1, 2.0])
    demo._wave_chart(tmp_path / "chart.png", waves, waves)
    assert figures[-1].axes[0].get_rmax() >= 1.1 * 3.0
    report._sea_figure(tmp_path / "sea.png", SimpleNamespace(sea={"waves": waves, "spectrum_fit": None},
                                                              sequence=SimpleNamespace(compass=False)))
    assert figures[-1].axes[-1].get_rmax() >= 1.1 * 2 * np.pi / 2.0
