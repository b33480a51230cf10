//! Identification of models of signals on board.

pub mod ar;
