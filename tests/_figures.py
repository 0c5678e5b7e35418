"""A check shared by the figure tests: texts inside the figure, panels apart."""


def texts_inside_and_panels_apart(fig) -> None:
    """Every visible axes of `fig`, with every text it draws (title, labels, drawn tick labels), lies inside the
    figure, and no two of them overlap (as savefig lays the figure out)."""
    from matplotlib.transforms import Bbox

    # as savefig draws it (the labels' places are set while drawing), without making the pixels: the same boxes
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    inside = fig.bbox.padded(1.0)
    boxes = []
    for ax in fig.axes:
        if not ax.get_visible() or not ax.axison:
            continue
        box = ax.get_tightbbox(renderer)
        assert inside.contains(box.x0, box.y0) and inside.contains(box.x1, box.y1), (ax.get_title(), box)
        boxes.append(box)
    for k, a in enumerate(boxes):
        for b in boxes[k + 1:]:
            overlap = Bbox.intersection(a, b)
            assert overlap is None or overlap.width < 2 or overlap.height < 2
