/* eha report html: draws the embedded plotly figures, swaps the figure of a selector, sorts
   and filters the tables. No request leaves the page. */
(function () {
  "use strict";
  var CONFIG = {responsive: true, displaylogo: false, scrollZoom: false,
                modeBarButtonsToRemove: ["sendDataToCloud"]};

  function readJSON(id) {
    return JSON.parse(document.getElementById(id).textContent);
  }

  var TEMPLATE = null;   /* the figures' shared look (one plotly template for all) */

  function draw(div, fig) {
    if (TEMPLATE === null) { TEMPLATE = readJSON("template"); }
    fig.layout.template = TEMPLATE;
    return Plotly.react(div, fig.data, fig.layout, CONFIG);
  }

  function setupChoice(select) {
    var div = document.getElementById(select.dataset.plot);
    var figs = readJSON(select.dataset.plot + "-data");
    select.addEventListener("change", function () { draw(div, figs[select.value]); });
    return draw(div, figs[select.value]);
  }

  function cellValue(td) {
    var v = td.getAttribute("data-v");
    if (v === null || v === "") { return null; }
    var n = Number(v);
    return isNaN(n) ? v.toLowerCase() : n;
  }

  function setupTable(table) {
    var heads = table.querySelectorAll("thead th");
    heads.forEach(function (th, col) {
      th.addEventListener("click", function () {
        var asc = th.getAttribute("aria-sort") !== "ascending";
        heads.forEach(function (h) { h.removeAttribute("aria-sort"); });
        th.setAttribute("aria-sort", asc ? "ascending" : "descending");
        var body = table.tBodies[0];
        var rows = Array.prototype.slice.call(body.rows);
        rows.sort(function (a, b) {
          var x = cellValue(a.cells[col]), y = cellValue(b.cells[col]);
          if (x === null) { return 1; }
          if (y === null) { return -1; }
          var r = (typeof x === typeof y) ? (x < y ? -1 : x > y ? 1 : 0)
                                          : String(x).localeCompare(String(y));
          return asc ? r : -r;
        });
        rows.forEach(function (r) { body.appendChild(r); });
      });
    });
    var filter = document.querySelector('input[data-table="' + table.id + '"]');
    if (filter) {
      filter.addEventListener("input", function () {
        var q = filter.value.trim().toLowerCase();
        Array.prototype.forEach.call(table.tBodies[0].rows, function (r) {
          r.style.display = (!q || r.textContent.toLowerCase().indexOf(q) >= 0) ? "" : "none";
        });
      });
    }
    /* a row that names a figure of a selector shows it there */
    Array.prototype.forEach.call(table.tBodies[0].rows, function (r) {
      var key = r.getAttribute("data-choice"), target = table.getAttribute("data-choice");
      if (key === null || !target) { return; }
      r.classList.add("pick");
      r.addEventListener("click", function () {
        var select = document.querySelector('select[data-plot="' + target + '"]');
        select.value = key;
        select.dispatchEvent(new Event("change"));
        document.getElementById(target).scrollIntoView({behavior: "smooth", block: "center"});
      });
    });
  }

  document.addEventListener("DOMContentLoaded", function () {
    var pending = [];
    document.querySelectorAll("div.plot[data-fig]").forEach(function (div) {
      pending.push(draw(div, readJSON(div.dataset.fig)));
    });
    document.querySelectorAll("select.choice").forEach(function (s) {
      pending.push(setupChoice(s));
    });
    document.querySelectorAll("table.data").forEach(setupTable);
    Promise.all(pending).then(function () {
      document.body.setAttribute("data-ready", "true");
    });
  });
})();
