// The pages' words in the reader's language: one message catalogue per language (i18n/<code>.json; every
// catalogue has every key, and the pages use only keys that exist: tests/test_page_words.py). The language: #lang=de
// in the page's address, else the first of the browser's languages that has a catalogue, else English. In the HTML, an element's
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

/** The menus message (/vr_teleop/menus) with its labels in the page's language. The menu files' labels are
 * English, a lab's own words, shown as written on an English page; other languages take the catalogue's word for
 * an emotion (emotion.<name>) or for the item's id (menu.<id>), and keep the file's label where it has none (a
 * lab's own items, the sentences, which follow the robot's language, and the clips' names). */
export function translateMenus(msg) {
  if (language === "en" || !msg || !Array.isArray(msg.menus) || !Array.isArray(msg.items)) return msg;
  const word = (item) => {
    if (item.command === "show_emotion") {
      try {
        const name = String(JSON.parse(item.args || "{}").name || "").replace(/^QT\//, "");
        if (`emotion.${name}` in catalogue) return catalogue[`emotion.${name}`];
      } catch { /* args that are not JSON: the server's own check reports them */ }
    }
    return catalogue[`menu.${item.id}`] ?? item.label;
  };
  return {...msg, menus: msg.menus.map((m) => ({...m, label: word(m)})),
          items: msg.items.map((item) => ({...item, label: word(item)}))};
}
