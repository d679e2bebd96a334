//! Names compared without following a pointer: a port's or property's name kept inline beside what it
//! names. A component names its ports and properties at every call (`ctx.read("in")`); comparing with
//! the name's own heap bytes costs a cache miss per lookup when the component runs rarely (hundreds of
//! components at 100 Hz), more than the rest of a short call.

/// Up to [`NameKey::INLINE`] bytes of a name, and its length; a longer name is marked and compared in
/// full by whoever holds it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct NameKey {
    len: u8,
    bytes: [u8; NameKey::INLINE],
}

impl NameKey {
    /// The longest name held whole.
    pub(crate) const INLINE: usize = 23;

    /// The key of `name`.
    pub(crate) fn of(name: &str) -> NameKey {
        let mut bytes = [0; Self::INLINE];
        for (to, from) in bytes.iter_mut().zip(name.bytes()) {
            *to = from;
        }
        let len = if name.len() <= Self::INLINE {
            u8::try_from(name.len()).unwrap_or(u8::MAX)
        } else {
            u8::MAX
        };
        NameKey { len, bytes }
    }

    /// Whether the key holds the whole name, so that equal keys mean equal names.
    pub(crate) fn is_whole(self) -> bool {
        self.len != u8::MAX
    }
}

/// The position of `wanted` among names given with their keys.
pub(crate) fn position_of<'a>(
    wanted: &str,
    names: impl Iterator<Item = (NameKey, &'a str)>,
) -> Option<usize> {
    let key = NameKey::of(wanted);
    let mut names = names;
    names.position(|(candidate, name)| candidate == key && (key.is_whole() || name == wanted))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_found_by_their_keys_and_long_ones_compared_in_full() {
        let long_a = "a_name_longer_than_the_inline_bytes_a";
        let long_b = "a_name_longer_than_the_inline_bytes_b";
        let names = ["in", "input", long_a, long_b, ""];
        let find = |wanted: &str| position_of(wanted, names.iter().map(|n| (NameKey::of(n), *n)));
        assert_eq!(find("in"), Some(0));
        assert_eq!(find("input"), Some(1));
        assert_eq!(find(long_a), Some(2));
        assert_eq!(find(long_b), Some(3), "same first bytes, told apart in full");
        assert_eq!(find(""), Some(4));
        assert_eq!(find("inp"), None);
        assert_eq!(find("in\0"), None, "a zero byte is not the padding");
        assert!(NameKey::of(&"x".repeat(23)).is_whole());
        assert!(!NameKey::of(&"x".repeat(24)).is_whole());
    }
}
