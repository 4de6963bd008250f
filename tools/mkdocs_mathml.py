"""MkDocs hook: math as MathML at build time, and readable Sphinx roles in the API reference.

``pymdownx.arithmatex`` (``generic: true``) wraps ``$...$`` and ``$$...$$`` in
``<span class="arithmatex">\\(...\\)</span>`` and ``<div class="arithmatex">\\[...\\]</div>``. This hook
replaces them with MathML from ``latex2mathml``, which every current browser renders natively: the site needs
no JavaScript and no network, so it builds and reads offline. A TeX command that ``latex2mathml`` does not know
(it would leave ``\\foo`` as text) or cannot parse is logged as a warning, which fails ``mkdocs build --strict``.

The docstrings cross-reference with Sphinx roles (:func:`simulate`, :meth:`~LieGroup.hat`), which Markdown
renders as ``:func:<code>simulate</code>``; the hook shows them as code (``~`` keeps the last name only).
"""

from __future__ import annotations

import html
import logging
import re

from latex2mathml.converter import convert

log = logging.getLogger("mkdocs.hooks.mathml")

_MATH = re.compile(
    r'<(?P<tag>span|div) class="arithmatex">\s*(?:\\\((?P<inline>.*?)\\\)|\\\[(?P<block>.*?)\\\])\s*</(?P=tag)>',
    re.DOTALL,
)
_ROLE = re.compile(r":(?:py:)?(?:func|meth|class|mod|attr|data|exc|obj):<code>(~?)([^<]+)</code>")
_LEFTOVER = re.compile(r">[^<]*\\[A-Za-z]+[^<]*<")


def _mathml(tex: str, display: str, where: str) -> str | None:
    try:
        out = convert(tex, display=display)
    except Exception as exc:  # latex2mathml raises its own exception types for syntax errors
        log.warning("%s: cannot convert math %r to MathML: %s", where, tex, exc or type(exc).__name__)
        return None
    if _LEFTOVER.search(out):
        log.warning("%s: math %r uses a TeX command latex2mathml does not know", where, tex)
        return None
    return out


def _role(m: re.Match) -> str:
    name = m.group(2)
    return f"<code>{name.rsplit('.', 1)[-1] if m.group(1) else name}</code>"


def on_page_content(html_text: str, page, config, files) -> str:
    """Replace arithmatex's math by MathML and Sphinx roles by code, in the rendered page."""
    where = page.file.src_uri

    def math(m: re.Match) -> str:
        block = m.group("block") is not None
        tex = html.unescape(m.group("block") if block else m.group("inline")).strip()
        out = _mathml(tex, "block" if block else "inline", where)
        if out is None:
            return m.group(0)
        return f'<div class="math">{out}</div>' if block else out

    return _ROLE.sub(_role, _MATH.sub(math, html_text))
