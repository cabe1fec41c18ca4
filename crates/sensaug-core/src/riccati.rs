//! Placeholder: being written on a branch.
