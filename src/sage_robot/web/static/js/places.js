// Places with human names: the place data's title when it has one, else the knowledge
// base's title of the place's document ("Guelly Delly café (GUELLY_DELLY)"), else the code
// name written as words. Code names stay in tooltips (title attributes) and the APIs.
import { api } from "./common.js";

const KB_TITLE = /^(.*\S)\s*\(([A-Z0-9_]+)\)\s*$/; // "Human title (CODE_NAME)"
const KEEP_UPPER = /^(?:[A-Z]{2,3}|\d\w*|\w*\d)$/; // ECE, 3D, LAB_1's "1": not words to capitalise
const WORDS = new Set(["LAB", "BAY", "BIO", "ENG", "HUB"]);

/** "GUELLY_DELLY" -> "Guelly Delly"; "ECE_LAB_1" -> "ECE Lab 1". */
export function humanName(code) {
  return String(code)
    .split(/[_\s]+/)
    .filter(Boolean)
    .map((w) => (KEEP_UPPER.test(w) && !WORDS.has(w) ? w : w.charAt(0) + w.slice(1).toLowerCase()))
    .join(" ");
}

/** A knowledge-base document title "Guelly Delly café (GUELLY_DELLY)" -> [code, title], else null. */
export function kbPlaceTitle(docTitle) {
  const m = KB_TITLE.exec(docTitle || "");
  return m ? [m[2], m[1]] : null;
}

/** Code name -> title, from the knowledge base's documents (empty when it has none). */
async function kbTitles() {
  const titles = new Map();
  const info = await api("/api/admin/info");
  if (!info.ok || info.data.kb) return titles; // data.kb: why the knowledge base is not there
  const docs = await api("/api/kb/documents");
  if (!docs.ok) return titles;
  const list = Array.isArray(docs.data) ? docs.data : docs.data.documents || [];
  for (const d of list) {
    const pair = kbPlaceTitle(d.title);
    if (pair) titles.set(...pair);
  }
  return titles;
}

let cachedTitles = null;

/** Every place with a ``title``; ``path`` is /api/places or /api/admin/places. */
export async function loadPlaces(path = "/api/places") {
  const { ok, data } = await api(path);
  if (!ok) return null;
  if (!cachedTitles) cachedTitles = await kbTitles().catch(() => new Map());
  return data.places.map((p) => ({ ...p, title: p.title || cachedTitles.get(p.name) || humanName(p.name) }));
}
