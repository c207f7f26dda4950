//! Which volume of the pair something is for: the fixed or the moving one.

/// Which volume of the pair a file replaces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    Fixed,
    Moving,
}

impl Side {
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Fixed => "fixed",
            Self::Moving => "moving",
        }
    }
}
