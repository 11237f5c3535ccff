//! Sequence readers (TUM RGB-D, 7-Scenes, the reference code's layout) and
//! format detection. Owned by the readers work; placeholder until it lands.
