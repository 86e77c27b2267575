//! Self-contained HTML report (images embedded as base64 data URIs).

use crate::RenderError;
use base64::Engine;
use std::path::Path;

/// Builder of one self-contained HTML page (headings, text, embedded PNGs, tables).
#[derive(Debug, Clone, Default)]
pub struct Report {
    title: String,
    body: String,
}

/// Escape text for HTML element content and attribute values.
fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for ch in s.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

const CSS: &str = "body{font-family:-apple-system,'Segoe UI',Helvetica,Arial,sans-serif;\
max-width:1200px;margin:2em auto;padding:0 1em;color:#222;line-height:1.45}\
h1{font-size:1.8em;border-bottom:2px solid #ddd;padding-bottom:.3em}\
h2{font-size:1.35em;margin-top:1.8em;border-bottom:1px solid #eee;padding-bottom:.2em}\
figure{margin:1.2em 0;text-align:center}figure img{max-width:100%;height:auto;border:1px solid #eee}\
figcaption{font-size:.92em;color:#555;margin-top:.4em}\
table{border-collapse:collapse;margin:1em 0;font-size:.95em}\
th,td{border:1px solid #ccc;padding:.3em .7em;text-align:right}\
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}\
tr:nth-child(even) td{background:#fafafa}\
pre{background:#f6f8fa;border:1px solid #e1e4e8;padding:.8em;overflow-x:auto;font-size:.88em}";

impl Report {
    /// Start a page with the given title (shown as the page heading).
    pub fn new(title: &str) -> Self {
        Report {
            title: title.to_string(),
            body: String::new(),
        }
    }

    /// Add a section heading (h2).
    pub fn heading(&mut self, text: &str) -> &mut Self {
        self.body.push_str(&format!("<h2>{}</h2>\n", escape(text)));
        self
    }

    /// Add a paragraph of plain text (HTML-escaped).
    pub fn paragraph(&mut self, text: &str) -> &mut Self {
        self.body.push_str(&format!("<p>{}</p>\n", escape(text)));
        self
    }

    /// Embed PNG bytes as a base64 data-URI image with a caption.
    pub fn image_png(&mut self, caption: &str, png: &[u8]) -> &mut Self {
        let b64 = base64::engine::general_purpose::STANDARD.encode(png);
        let cap = escape(caption);
        self.body.push_str(&format!(
            "<figure><img src=\"data:image/png;base64,{b64}\" alt=\"{cap}\"><figcaption>{cap}</figcaption></figure>\n"
        ));
        self
    }

    /// Add a table with a header row and string cells (HTML-escaped).
    pub fn table(&mut self, header: &[&str], rows: &[Vec<String>]) -> &mut Self {
        let mut t = String::from("<table>\n<thead><tr>");
        for h in header {
            t.push_str(&format!("<th>{}</th>", escape(h)));
        }
        t.push_str("</tr></thead>\n<tbody>\n");
        for r in rows {
            t.push_str("<tr>");
            for cell in r {
                t.push_str(&format!("<td>{}</td>", escape(cell)));
            }
            t.push_str("</tr>\n");
        }
        t.push_str("</tbody>\n</table>\n");
        self.body.push_str(&t);
        self
    }

    /// Add preformatted text (e.g. parameters as JSON), HTML-escaped.
    pub fn preformatted(&mut self, text: &str) -> &mut Self {
        self.body
            .push_str(&format!("<pre>{}</pre>\n", escape(text)));
        self
    }

    /// The complete HTML document.
    pub fn to_html(&self) -> String {
        let t = escape(&self.title);
        format!(
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
<title>{t}</title>\n<style>{CSS}</style>\n</head>\n<body>\n<h1>{t}</h1>\n{}</body>\n</html>\n",
            self.body
        )
    }

    /// Write the HTML document to `path`.
    pub fn write(&self, path: &Path) -> Result<(), RenderError> {
        std::fs::write(path, self.to_html()).map_err(|source| RenderError::Io {
            path: path.to_path_buf(),
            source,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_contents() {
        let mut r = Report::new("Run <1>");
        r.heading("Results")
            .paragraph("a < b && c > d \"quoted\"")
            .image_png("fig 1", &[0x89, b'P', b'N', b'G'])
            .table(
                &["metric", "value"],
                &[
                    vec!["RMSE".into(), "3.2".into()],
                    vec!["bias".into(), "<0.1>".into()],
                ],
            )
            .preformatted("{\"a\": 1}");
        let h = r.to_html();
        assert!(h.starts_with("<!DOCTYPE html>"));
        assert!(h.contains("<title>Run &lt;1&gt;</title>"));
        assert!(h.contains("<h2>Results</h2>"));
        assert!(h.contains("<p>a &lt; b &amp;&amp; c &gt; d &quot;quoted&quot;</p>"));
        assert!(!h.contains("a < b"));
        assert!(h.contains("data:image/png;base64,iVBORw=="));
        assert!(h.contains("<tr><td>RMSE</td><td>3.2</td></tr>"));
        assert!(h.contains("<tr><td>bias</td><td>&lt;0.1&gt;</td></tr>"));
        assert!(h.contains("<th>metric</th><th>value</th>"));
        assert!(h.contains("<pre>{&quot;a&quot;: 1}</pre>"));
    }

    #[test]
    fn write_errors_on_bad_path() {
        let r = Report::new("x");
        let dir = tempfile::tempdir().unwrap();
        let bad = dir.path().join("no_such_dir").join("r.html");
        assert!(matches!(r.write(&bad), Err(RenderError::Io { .. })));
        let good = dir.path().join("r.html");
        r.write(&good).unwrap();
        assert!(
            std::fs::read_to_string(good)
                .unwrap()
                .contains("<h1>x</h1>")
        );
    }
}
