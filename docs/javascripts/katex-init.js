// Render the TeX that pymdownx.arithmatex (generic mode) leaves in the page: inline
// \( … \) in span.arithmatex, display \[ … \] in div.arithmatex. KaTeX is served by the
// site itself (assets/katex), so the mathematics renders offline.
function jaxhystRenderMath(root) {
  for (const el of root.querySelectorAll(".arithmatex")) {
    if (el.dataset.rendered) continue;
    const text = el.textContent.trim();
    const display = text.startsWith("\\[");
    katex.render(text.slice(2, -2), el, {
      displayMode: display,
      throwOnError: false, // a bad formula shows in red (.katex-error), the page still works
    });
    el.dataset.rendered = "1";
  }
}

if (typeof document$ !== "undefined") {
  document$.subscribe(() => jaxhystRenderMath(document.body)); // Material's page observable
} else {
  document.addEventListener("DOMContentLoaded", () => jaxhystRenderMath(document.body));
}
