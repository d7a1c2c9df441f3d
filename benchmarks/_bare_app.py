"""A bare Panel page dressed as the app, for ``bench_app.py --baseline``.

    python benchmarks/_bare_app.py SESSION_NAME --port P

Serves, like ``ccdcore app``, the app's template (``AppTemplate``, a ``BootstrapTemplate``,
with the app's ``AppDesign``, title, header colours, sidebar width and raw CSS) with the same
resources (the extensions ``ccdcore_app.main`` loads, its static folder and ``bokeh_speed.js``,
``/liveness``), but a trivial content: the header line "Session: NAME" and one Markdown pane "Loaded NAME" in
the main area. Its first view is what any Panel page of that template costs on this machine.
"""
from __future__ import annotations

import argparse
import html


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session_name")
    ap.add_argument("--port", type=int, required=True)
    args = ap.parse_args()

    import panel as pn

    # the same extensions, configuration and design as the app (imported, not copied)
    from ccdcore_app import main as app_main
    from ccdcore_app.main import _CSS, TITLE, AppDesign, server_resources

    # (an older ccdcore_app, measured for comparison, has no AppTemplate: its base class)
    AppTemplate = getattr(app_main, "AppTemplate", pn.template.BootstrapTemplate)

    name = args.session_name

    def app() -> pn.template.BaseTemplate:
        template = AppTemplate(
            design=AppDesign, title=TITLE, sidebar_width=250, header_background="#1f3b57",
            header_color="#ffffff", busy_indicator=None)
        template.header.append(pn.pane.HTML(
            f"<div class='ccd-session'>Session: <code>{html.escape(name)}</code></div>",
            stylesheets=[_CSS], sizing_mode="stretch_width", margin=(12, 10)))
        template.main.append(pn.pane.Markdown(f"## Session\n\nLoaded {name}",
                                              sizing_mode="stretch_width"))
        template.config.raw_css.append(_CSS)
        return template

    address = "127.0.0.1"
    origins = [f"{address}:{args.port}", f"localhost:{args.port}", f"127.0.0.1:{args.port}"]
    pn.serve({"/": app}, port=args.port, address=address, show=False, title="ccdcore",
             liveness=True, websocket_origin=origins, start=True, **server_resources())


if __name__ == "__main__":
    main()
