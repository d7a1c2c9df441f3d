"""ccdcore_app.batch.frozen_models: the model graph is walked once at the end, and only if it changed."""
from __future__ import annotations

import numpy as np
from bokeh.document import Document
from bokeh.layouts import column
from bokeh.models import ColumnDataSource, Div
from bokeh.plotting import figure

from ccdcore_app.batch import frozen_models


def _doc():
    doc = Document()
    source = ColumnDataSource({"x": [0.0], "y": [0.0]})
    fig = figure()
    fig.scatter("x", "y", source=source)
    root = column(fig)
    doc.add_root(root)
    walks = []
    recompute = doc.models.recompute
    doc.models.recompute = lambda: (walks.append(1), recompute())[1]
    return doc, root, source, fig, walks


def test_a_data_change_does_not_walk_the_graph():
    doc, _, source, fig, walks = _doc()
    with frozen_models(doc):
        source.data = {"x": np.arange(3.0), "y": np.arange(3.0)}
        fig.title.text = "new"
    assert walks == []
    assert "_push_freeze" not in vars(doc.models) and doc.models._freeze_count == 0


def test_a_new_model_is_registered_with_one_walk():
    doc, root, _, _, walks = _doc()
    div = Div(text="added")
    with frozen_models(doc):
        root.children = [*root.children, div]      # Bokeh invalidates: a model in the value
        second = Div(text="another")
        root.children = [*root.children, second]
        assert walks == []                         # deferred to the end
    assert walks == [1]
    assert doc.models.get_by_id(div.id) is div and doc.models.get_by_id(second.id) is second


def test_a_new_root_and_nesting():
    doc, _, _, _, walks = _doc()
    extra = Div(text="root")
    with frozen_models(doc):
        with frozen_models(doc):                   # nested: the outer decides
            doc.add_root(extra)                    # a nested Bokeh freeze marks a change
        assert walks == []
    assert walks == [1] and doc.models.get_by_id(extra.id) is extra
    with frozen_models(doc):
        pass
    assert walks == [1]


def test_an_error_inside_leaves_the_document_usable():
    doc, root, _, _, walks = _doc()
    try:
        with frozen_models(doc):
            root.children = [*root.children, Div(text="x")]
            raise RuntimeError("boom")
    except RuntimeError:
        pass
    assert walks == [1] and doc.models._freeze_count == 0
    div = Div(text="later")
    root.children = [*root.children, div]          # Bokeh's own invalidate works again
    assert doc.models.get_by_id(div.id) is div
