//! Dailies on a render farm: a shooting day as an Open Job Description job bundle
//! ([`job`]), takes replayed in chunks of frames that each warm up on the frames before
//! them, and the chunks of a take joined into the take a single replay writes
//! ([`merge`]), checked through the `take.json` every replay leaves ([`manifest`]).

pub mod job;
pub mod manifest;
pub mod merge;

pub use job::{Chunk, JobSpec, JobTake, ReplayOption, chunk_ranges};
pub use manifest::{
    Fingerprint, MANIFEST_FILE, ManifestError, TakeManifest, list_outputs, session_fingerprint,
};
pub use merge::{MergeError, MergeSummary, find_chunks, merge_chunks};
