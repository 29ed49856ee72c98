//! Place recognition: a bag of binary words trained online from the sequence's keyframes
//! ([`vocabulary`]) and the keyframe database queried for loop candidates ([`database`]).

pub mod database;
pub mod vocabulary;

pub use database::{DatabaseParams, KeyFrameDatabase};
pub use vocabulary::{BowVector, Vocabulary, VocabularyParams, WordId};
