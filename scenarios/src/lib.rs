//! placeholder replaced by the scenarios work
