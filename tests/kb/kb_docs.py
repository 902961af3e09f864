"""Documents of every supported format, built in the test (PDF with fpdf2, DOCX with
python-docx), about facts the corpus does not contain."""

from __future__ import annotations

import io

HTML = b"""<!doctype html><html><head><title>Planetarium shows</title></head><body>
<nav><a href="/">Home</a> | <a href="/about">About us</a> | <a href="/contact">Contact</a></nav>
<main><article><h1>Planetarium shows</h1>
<p>The campus planetarium projects star shows under its dome every Friday evening at eight.
Tickets are free for students and cost five dollars for guests.</p>
<h2>Telescope nights</h2>
<p>On clear nights the astronomy club opens the rooftop observatory so visitors can look at
Saturn's rings and the craters of the Moon through the big refracting telescope.</p>
</article></main>
<footer>Copyright the university. Privacy policy. Cookie settings.</footer>
</body></html>"""

MARKDOWN = b"""# Greenhouse

## Plants
The rooftop greenhouse grows tomatoes, basil and orchids for the biology department.

## Visiting
Volunteers water the plants every morning; visitors may tour it on Mondays.
"""

TEXT = b"""Bicycle repair station

A free bicycle repair stand with a pump and tools is outside the east entrance.

Riders can fix a flat tire there at any hour."""


def make_pdf(pages: list[str], title: str = "Library handbook") -> bytes:
    from fpdf import FPDF

    pdf = FPDF()
    pdf.set_title(title)
    pdf.set_font("Helvetica", size=12)
    for text in pages:
        pdf.add_page()
        pdf.multi_cell(0, 8, text)
    return bytes(pdf.output())


def make_docx(sections: dict[str, list[str]], title: str = "Swimming pool guide") -> bytes:
    import docx

    document = docx.Document()
    document.core_properties.title = title
    document.add_heading(title, level=0)
    for heading, paragraphs in sections.items():
        document.add_heading(heading, level=1)
        for text in paragraphs:
            document.add_paragraph(text)
    buf = io.BytesIO()
    document.save(buf)
    return buf.getvalue()


PDF_PAGES = [
    "The library lends laptops for up to three days to any student with an ID card.",
    "Silent study rooms on the third floor can be booked online for two hours at a time.",
]
DOCX_SECTIONS = {
    "Lanes": ["The indoor pool has eight lanes of twenty-five metres for lap swimming."],
    "Lifeguards": ["Lifeguards are on duty whenever the pool is open, from six to nine."],
}
