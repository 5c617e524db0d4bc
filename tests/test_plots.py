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
