// bagport QA report: the episode table sorts and filters in the browser (hand-written, no library).
// Row: [run, episode, bag, score, verdict(0 pass 1 warn 2 fail), excluded, fails[], warns[], folder,
//       day, robot, has detail, position in its run, reason]
(function () {
  "use strict";
  var D = JSON.parse(document.getElementById("qa-data").textContent);
  var VERDICTS = ["pass", "warn", "fail"];
  var PAGE = 100;
  var sortCol = 3, sortDir = 1, page = 0;
  function $(id) { return document.getElementById(id); }
  function esc(text) {
    return String(text).replace(/[&<>"']/g, function (c) {
      return { "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c];
    });
  }
  function pad(n, width) { var s = String(n); while (s.length < width) { s = "0" + s; } return s; }
  function detail(r) { return "details/run-" + pad(r[0], 3) + "/" + pad(r[12], 6) + ".html"; }
  function checkNames(r) {
    return r[6].map(function (i) { return D.checks[i]; }).concat(r[7].map(function (i) { return D.checks[i]; }));
  }
  var KEYS = [
    function (r) { return r[0] * 1e9 + r[12]; },
    function (r) { return r[1] === null ? -1 : r[1]; },
    function (r) { return r[2]; },
    function (r) { return r[3]; },
    function (r) { return r[4]; },
    function (r) { return r[6].length * 1000 + r[7].length; },
    function (r) { return D.folders[r[8]]; },
    function (r) { return D.days[r[9]]; },
    function (r) { return D.robots[r[10]]; }
  ];
  function matches(r, verdict, check, run, text) {
    if (verdict === "excluded" && !r[5]) { return false; }
    if (verdict && verdict !== "excluded" && VERDICTS[r[4]] !== verdict) { return false; }
    if (check !== "" && r[6].indexOf(+check) < 0 && r[7].indexOf(+check) < 0) { return false; }
    if (run !== "" && r[0] !== +run) { return false; }
    if (text) {
      var hay = [r[2], D.folders[r[8]], D.days[r[9]], D.robots[r[10]], r[13]].concat(checkNames(r)).join(" ");
      if (hay.toLowerCase().indexOf(text) < 0) { return false; }
    }
    return true;
  }
  function row(r) {
    var verdict = VERDICTS[r[4]];
    var bag = r[11] ? '<a href="' + detail(r) + '">' + esc(r[2]) + "</a>" : esc(r[2]);
    var checks = r[6].map(function (i) { return '<span class="chk-fail">' + esc(D.checks[i]) + "</span>"; })
      .concat(r[7].map(function (i) { return '<span class="chk-warn">' + esc(D.checks[i]) + "</span>"; }));
    return "<tr data-verdict=\"" + verdict + "\"><td>" + r[0] + "</td><td>" + (r[1] === null ? "excluded" : r[1]) +
      "</td><td>" + bag + "</td><td>" + r[3].toFixed(2) + '</td><td class="' + verdict + '">' + verdict +
      "</td><td>" + checks.join(" ") + "</td><td>" + esc(D.folders[r[8]]) + "</td><td>" + esc(D.days[r[9]]) +
      "</td><td>" + esc(D.robots[r[10]]) + "</td><td>" + esc(r[13]) + "</td></tr>";
  }
  function render() {
    var verdict = $("f-verdict").value, check = $("f-check").value, run = $("f-run").value;
    var text = $("f-text").value.trim().toLowerCase();
    var list = D.rows.filter(function (r) { return matches(r, verdict, check, run, text); });
    var key = KEYS[sortCol];
    list.sort(function (a, b) {
      var x = key(a), y = key(b);
      return (x < y ? -1 : x > y ? 1 : KEYS[0](a) - KEYS[0](b)) * sortDir;
    });
    var pages = Math.max(1, Math.ceil(list.length / PAGE));
    page = Math.min(page, pages - 1);
    var shown = list.slice(page * PAGE, (page + 1) * PAGE);
    $("ep-body").innerHTML = shown.map(row).join("");
    $("ep-count").textContent = list.length ? (page * PAGE + 1) + "-" + (page * PAGE + shown.length) + " of " +
      list.length + " episode(s)" : "no episode matches";
    var heads = document.querySelectorAll("#episodes th[data-col]");
    for (var i = 0; i < heads.length; i++) {
      heads[i].className = +heads[i].getAttribute("data-col") === sortCol ? (sortDir > 0 ? "sorted-asc" : "sorted-desc") : "";
    }
  }
  var select = $("f-check");
  D.checks.map(function (name, i) { return [name, i]; }).sort().forEach(function (item) {
    var option = document.createElement("option");
    option.value = String(item[1]);
    option.textContent = item[0];
    select.appendChild(option);
  });
  ["f-verdict", "f-check", "f-run", "f-text"].forEach(function (id) {
    $(id).addEventListener("input", function () { page = 0; render(); });
  });
  $("prev").addEventListener("click", function () { page = Math.max(0, page - 1); render(); });
  $("next").addEventListener("click", function () { page += 1; render(); });
  var heads = document.querySelectorAll("#episodes th[data-col]");
  for (var i = 0; i < heads.length; i++) {
    heads[i].addEventListener("click", function (event) {
      var col = +event.currentTarget.getAttribute("data-col");
      sortDir = col === sortCol ? -sortDir : 1;
      sortCol = col;
      render();
    });
  }
  render();
})();
