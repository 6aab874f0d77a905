"""mkdocs hook: the docstrings' reST cross-reference roles and literals (``:class:`~geoface.X```,
``:func:`f```, ...) shown as code, as Markdown would show them, not as raw markup."""
from __future__ import annotations

import re

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|exc|obj|const):(?:<code>|`)(~?)([^<`]+)(?:</code>|`)")


def _name(m: re.Match) -> str:
    target = m.group(2)
    return f"<code>{target.rsplit('.', 1)[-1] if m.group(1) else target}</code>"


_CODE = re.compile(r"<code>(.*?)</code>", re.S)


def on_page_content(html, page, config, files):  # noqa: ARG001 — mkdocs' hook signature
    html = _ROLE.sub(_name, html)
    # reST literals (``x``) inside what is already shown as code (a numpy "type" column)
    return _CODE.sub(lambda m: "<code>" + m.group(1).replace("``", "") + "</code>", html)
