//! Markdown tables, the one way the tools print them: a header row, a separator giving each
//! column's alignment (`---` text, `---:` numbers), and rows of cells, `| a | b |` each.

use std::fmt;

/// A Markdown table (module doc).
#[derive(Clone, Debug)]
pub struct Table {
    header: Vec<String>,
    /// Per column: right-aligned (numbers).
    right: Vec<bool>,
    rows: Vec<Vec<String>>,
}

impl Table {
    /// Columns named `header`, aligned as `align` says per column: `l` (text) or `r`
    /// (numbers), e.g. `"llrr"`.
    pub fn new(header: &[&str], align: &str) -> Self {
        assert_eq!(header.len(), align.len(), "one alignment per column");
        assert!(
            align.chars().all(|c| c == 'l' || c == 'r'),
            "alignments are l or r"
        );
        Table {
            header: header.iter().map(|h| h.to_string()).collect(),
            right: align.chars().map(|c| c == 'r').collect(),
            rows: Vec::new(),
        }
    }

    /// Appends a row; it must have one cell per column.
    pub fn row(&mut self, cells: impl IntoIterator<Item = String>) -> &mut Self {
        let cells: Vec<String> = cells.into_iter().collect();
        assert_eq!(cells.len(), self.header.len(), "one cell per column");
        self.rows.push(cells);
        self
    }

    /// The header and separator lines, for printing rows as they come ([`Table::line`]).
    pub fn head(&self) -> String {
        let rule: Vec<&str> = self
            .right
            .iter()
            .map(|&r| if r { "---:" } else { "---" })
            .collect();
        format!("| {} |\n|{}|\n", self.header.join(" | "), rule.join("|"))
    }

    /// One row's line, not kept (one cell per column).
    pub fn line(&self, cells: impl IntoIterator<Item = String>) -> String {
        let cells: Vec<String> = cells.into_iter().collect();
        assert_eq!(cells.len(), self.header.len(), "one cell per column");
        format!("| {} |\n", cells.join(" | "))
    }
}

impl fmt::Display for Table {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.head())?;
        for row in &self.rows {
            writeln!(f, "| {} |", row.join(" | "))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::Table;

    #[test]
    fn a_table_prints_its_header_alignment_and_rows() {
        let mut t = Table::new(&["face", "ms"], "lr");
        t.row(["neutral".to_string(), format!("{:.1}", 8.94)]);
        assert_eq!(
            t.to_string(),
            "| face | ms |\n|---|---:|\n| neutral | 8.9 |\n"
        );
        assert_eq!(
            t.head() + &t.line(["x".to_string(), "1".to_string()]),
            "| face | ms |\n|---|---:|\n| x | 1 |\n"
        );
    }

    #[test]
    #[should_panic(expected = "one cell per column")]
    fn a_row_of_the_wrong_width_is_a_bug() {
        Table::new(&["a", "b"], "ll").row(["x".to_string()]);
    }
}
