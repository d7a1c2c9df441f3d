// Two BokehJS reads that force the browser to recompute styles, made cheap (docs/notes.md,
// "Where the app's time goes").  Loaded by the app's template after bokeh.min.js.
//
// 1. Every line, fill, text and hatch property read first asks the CSS cascade for a `--bk-*`
//    variable (getComputedStyle(el).getPropertyValue) and falls back to the model's value
//    (bokeh/bokeh#15286).  The app defines no such variable (tests/app/test_bokeh_speed.py
//    checks its stylesheets and Panel's and Bokeh's), so the answer is always "": return it
//    without touching the cascade.  After a DOM change each read recomputed the styles of the
//    whole page: 40 % of the browser's work on a first page visit.
// 2. A plot's base font size (getComputedStyle(el).fontSize) is read for every text it
//    measures; the app never changes it, so a plot keeps the first answer it gets.
(function () {
  "use strict";
  function patch() {
    const Bokeh = window.Bokeh;
    if (Bokeh == null || typeof Bokeh.require !== "function") {
      return false;
    }
    if (window.ccdBokehSpeed != null) {
      return true;
    }
    const done = [];
    try {
      const visual = Bokeh.require("core/visuals/visual");
      if (visual && visual.VisualProperties &&
          typeof visual.VisualProperties.prototype._get_css_value === "function") {
        visual.VisualProperties.prototype._get_css_value = function () { return ""; };
        done.push("css-variables");
      }
    } catch (e) { /* another BokehJS: leave it as it is */ }
    try {
      const canvas = Bokeh.require("models/plots/plot_canvas");
      const proto = canvas && canvas.PlotView ? canvas.PlotView.prototype : null;
      const desc = proto ? Object.getOwnPropertyDescriptor(proto, "base_font_size") : null;
      if (desc && typeof desc.get === "function") {
        Object.defineProperty(proto, "base_font_size", {
          configurable: true,
          get() {
            if (this._ccd_base_font_size == null) {
              const value = desc.get.call(this);
              if (value == null) {
                return value;     // not laid out yet: ask again next time
              }
              this._ccd_base_font_size = value;
            }
            return this._ccd_base_font_size;
          },
        });
        done.push("base-font-size");
      }
    } catch (e) { /* idem */ }
    window.ccdBokehSpeed = done;
    return true;
  }
  if (!patch()) {
    document.addEventListener("DOMContentLoaded", patch);
  }
})();
