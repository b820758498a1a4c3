//! Design and verdict streams (`docs/design.md`, "How we measure"): the seeds or draws on which
//! a study's settings were chosen never judge them. A stream is a range of seed or draw
//! numbers; those below the study's design count chose its settings.

/// One study's stream of seeds or draws.
pub struct Stream<'a> {
    /// "Seeds" or "Held-out draws", as the sentence starts.
    pub noun: &'a str,
    /// The first seed or draw, and how many.
    pub first: usize,
    pub count: usize,
    /// Seeds or draws `0..design` chose the settings.
    pub design: usize,
    /// What was chosen on them, as a noun phrase ("the optimisers' settings (…)").
    pub chosen: &'a str,
    /// The command-line flag that starts a stream (`--first-seed`).
    pub flag: &'a str,
}

impl Stream<'_> {
    /// Whether no seed or draw of the stream chose a setting.
    pub fn is_verdict(&self) -> bool {
        self.first >= self.design
    }

    /// The page's sentence on which stream its tables come from.
    pub fn text(&self) -> String {
        let (first, last) = (self.first, self.first + self.count.max(1) - 1);
        let (noun, chosen, design) = (self.noun, self.chosen, self.design);
        if self.is_verdict() {
            format!("{noun} {first}–{last}: a verdict stream. Nothing was chosen on them; {chosen} were chosen on 0–{}, the design stream.", design - 1)
        } else if last < design {
            format!("{noun} {first}–{last}: the design stream. {} were chosen on them, so the verdicts below are not tests on fresh data; those come from `{} {design}`.", capitalised(chosen), self.flag)
        } else {
            format!("{noun} {first}–{last}: 0–{} of them chose {chosen} and the rest did not, a mixed stream, not a verdict on fresh data.", design - 1)
        }
    }
}

/// The working folder of a stream starting at `first` under a study's folder `name`: `name`
/// itself for the stream from 0, `name-from-N` for one from N. A run's settings (its first seed
/// or draw among them) fix its journals, so each stream keeps its own.
pub fn folder(name: &str, first: usize) -> String {
    if first == 0 {
        name.to_string()
    } else {
        format!("{name}-from-{first}")
    }
}

/// `s` with its first letter in upper case.
fn capitalised(s: &str) -> String {
    let mut c = s.chars();
    c.next()
        .map(|f| f.to_uppercase().chain(c).collect())
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::Stream;

    fn stream(first: usize) -> Stream<'static> {
        Stream {
            noun: "Seeds",
            first,
            count: 10,
            design: 10,
            chosen: "the settings",
            flag: "--first-seed",
        }
    }

    #[test]
    fn a_stream_says_whether_it_chose_its_settings() {
        assert!(stream(0)
            .text()
            .contains("the design stream. The settings were chosen on them"));
        assert!(stream(0).text().contains("`--first-seed 10`"));
        assert!(stream(10).is_verdict());
        assert!(stream(10)
            .text()
            .starts_with("Seeds 10–19: a verdict stream"));
        assert!(stream(5).text().contains("a mixed stream"));
        assert_eq!(super::folder("eval", 0), "eval");
        assert_eq!(super::folder("eval", 20), "eval-from-20");
    }
}
