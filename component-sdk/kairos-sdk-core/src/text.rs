//! Text helpers for packs that read files of their own (calibrations, frame trees) and report errors
//! where they are.

/// The line and column (both from 1, columns in bytes) of byte `offset` in `text`: what a located
/// diagnostic (`file:line:column: what`) prints. An offset past the end is the end.
pub fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = text.get(..offset.min(text.len())).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let column = before.rfind('\n').map_or(before.len(), |n| before.len() - n - 1) + 1;
    (line, column)
}

#[cfg(test)]
mod tests {
    use super::line_column;

    #[test]
    fn offsets_become_lines_and_columns_from_one() {
        let text = "ab\ncde\n";
        assert_eq!(line_column(text, 0), (1, 1));
        assert_eq!(line_column(text, 4), (2, 2));
        assert_eq!(line_column(text, 100), (3, 1));
    }
}
