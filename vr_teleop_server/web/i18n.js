// The pages' words in the reader's language: one message catalogue per language (i18n/<code>.json; every catalogue
// has every key, and the pages use only keys that exist: tests/test_page_words.py). The language: #lang=de in the page's
// address, else the first of the browser's languages that has a catalogue, else English. In the HTML, an element's
// text comes from the key in its data-i18n attribute (its title from data-i18n-title, a field's placeholder from
// data-i18n-placeholder); in the scripts, from t(key, {name: value}) for "{name}" in the text.

export const PAGE_LANGUAGES = ["en", "de", "fr"];

export function pageLanguage(hash = location.hash, preferred = navigator.languages || [navigator.language]) {
  const asked = new URLSearchParams(hash.slice(1)).get("lang");
  for (const code of [asked, ...preferred]) {
    const short = (code || "").toLowerCase().split("-")[0];
    if (PAGE_LANGUAGES.includes(short)) return short;
  }
  return "en";
}

export const language = pageLanguage();
const catalogue = await (await fetch(new URL(`./i18n/${language}.json`, import.meta.url))).json();

export function t(key, vars = {}) {
  const text = catalogue[key] ?? key;
  return text.replace(/\{(\w+)\}/g, (whole, name) => (name in vars ? String(vars[name]) : whole));
}

export function translatePage(root = document) {
  document.documentElement.lang = language;
  for (const node of root.querySelectorAll("[data-i18n]")) node.textContent = t(node.dataset.i18n);
  for (const node of root.querySelectorAll("[data-i18n-title]")) node.title = t(node.dataset.i18nTitle);
  for (const node of root.querySelectorAll("[data-i18n-placeholder]")) {
    node.placeholder = t(node.dataset.i18nPlaceholder);
  }
}
