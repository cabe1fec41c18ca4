//! Placeholder: being written on the bridge-rs branch.
