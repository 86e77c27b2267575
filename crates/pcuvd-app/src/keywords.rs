//! The command's flags in its messages, rewritten as keywords for a front end that takes options
//! as keywords (the Python package): one wording of every error and note, each user reading the
//! option as they gave it (`--f-number -1: ...` on the command line, `f_number=-1: ...` in Python).

/// Words that, after a flag, are its value rather than the message's next word.
const VALUE_WORDS: [&str; 8] = [
    "on",
    "off",
    "auto",
    "whole",
    "none",
    "simultaneous",
    "kasai",
    "loupas",
];

/// `text` with each `--flag` written as `keyword_of` spells it, given the flag's name with `_`
/// for `-` (`None`: left as the command spells it), and the value the message gives it as
/// `keyword=VALUE` (a bare word quoted as a Python string): `--flag=VALUE`, and `--flag VALUE`
/// where VALUE is a number, a quoted string, one of [`VALUE_WORDS`] or any word before a colon
/// (`--svd-low banana: ...`). A spelling that holds its own value (`force=True` for a switch)
/// takes none. A `--` inside a word (a path's `run--grid`) is left alone.
pub fn flags_as_keywords(text: &str, keyword_of: impl Fn(&str) -> Option<String>) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = rest.find("--") {
        let (before, from_dashes) = rest.split_at(at);
        out.push_str(before);
        let starts_a_word = out
            .chars()
            .next_back()
            .is_none_or(|c| c.is_whitespace() || "([`'\",;".contains(c));
        let after = &from_dashes[2..];
        let name_len = after
            .find(|c: char| !(c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-'))
            .unwrap_or(after.len());
        let name = after[..name_len].trim_end_matches('-');
        let keyword = (starts_a_word && name.starts_with(|c: char| c.is_ascii_lowercase()))
            .then(|| keyword_of(&name.replace('-', "_")))
            .flatten();
        let Some(keyword) = keyword else {
            out.push_str("--");
            rest = after;
            continue;
        };
        out.push_str(&keyword);
        rest = &after[name.len()..];
        let (value, after_value) = if keyword.contains('=') {
            (None, rest)
        } else if let Some(given) = rest.strip_prefix('=') {
            let end = given
                .find(|c: char| c.is_whitespace() || ",;)".contains(c))
                .unwrap_or(given.len());
            let value = given[..end].trim_end_matches(':');
            (Some(value), &given[value.len()..])
        } else if let Some(spaced) = rest.strip_prefix(' ') {
            let token = spaced.split(char::is_whitespace).next().unwrap_or("");
            let value = token.trim_end_matches([':', ',', ';', ')']);
            let before_colon = token[value.len()..].starts_with(':');
            let is_value = !value.is_empty()
                && (before_colon
                    || value.parse::<f64>().is_ok()
                    || value.starts_with('"')
                    || VALUE_WORDS.contains(&value));
            (is_value.then_some(value), &spaced[value.len()..])
        } else {
            (None, rest)
        };
        if let Some(value) = value {
            out.push('=');
            out.push_str(&python_value(value));
            rest = after_value;
        }
    }
    out.push_str(rest);
    out
}

/// A value as written in a message, as Python would write it: numbers, quoted strings and lists
/// as they are, a bare word in quotes.
fn python_value(value: &str) -> String {
    if value.parse::<f64>().is_ok() || value.starts_with(['"', '[', '(', '\'']) {
        value.to_string()
    } else {
        format!("\"{value}\"")
    }
}

#[cfg(test)]
mod tests {
    use super::flags_as_keywords;

    fn known(name: &str) -> Option<String> {
        if name == "force" {
            return Some("force=True".into());
        }
        [
            "f_number",
            "grid",
            "dynamics",
            "dealias",
            "heart_rate",
            "cardiac_triggers",
            "tissue_motion",
            "tissue_db",
            "preset",
            "frames",
        ]
        .contains(&name)
        .then(|| name.to_string())
    }

    #[test]
    fn flags_become_keywords_with_the_values_the_messages_give_them() {
        for (cli, python) in [
            (
                "--f-number -1: must be within [0.1, 100]",
                "f_number=-1: must be within [0.1, 100]",
            ),
            (
                "--grid \"a,b\": expected five numbers in mm",
                "grid=\"a,b\": expected five numbers in mm",
            ),
            (
                "no RI maps: too short (--dynamics=off silences this)",
                "no RI maps: too short (dynamics=\"off\" silences this)",
            ),
            (
                "--heart-rate and --cardiac-triggers: give one",
                "heart_rate and cardiac_triggers: give one",
            ),
            (
                "--tissue-motion moves tissue: add some with --tissue-db",
                "tissue_motion moves tissue: add some with tissue_db",
            ),
            ("--dealias auto: no effect", "dealias=\"auto\": no effect"),
            (
                "nothing was unwrapped (--dealias 2 had no effect)",
                "nothing was unwrapped (dealias=2 had no effect)",
            ),
            (
                "give --dynamics off, a longer --frames",
                "give dynamics=\"off\", a longer frames",
            ),
            (
                "the run made none (--dynamics off)",
                "the run made none (dynamics=\"off\")",
            ),
            ("--grid \"a b\": two words", "grid=\"a b\": two words"),
            ("--frames must be at least 1", "frames must be at least 1"),
            (
                "pass --force to replace it; --force 2 is not a count",
                "pass force=True to replace it; force=True 2 is not a count",
            ),
            ("--frames=0", "frames=0"),
            ("--frames=0, or more", "frames=0, or more"),
            ("--dealias: invalid", "dealias: invalid"),
        ] {
            assert_eq!(flags_as_keywords(cli, known), python, "{cli}");
        }
    }

    #[test]
    fn what_is_not_a_keyword_stays_as_written() {
        for text in [
            "--out results: a folder",
            "give --angles in degrees",
            "/data/run--grid/x.mat: not found",
            "a -- b",
            "--",
            "ends with --",
            "--Grid 3: upper case",
            "--9 lives",
            "é--grid",
        ] {
            assert_eq!(flags_as_keywords(text, known), text);
        }
    }
}
