//! Traffic measured on recordings and the world calibrated to it: drivers' go / wait decisions
//! at yield lines ([`decisions`]) and the gaps they were offered there ([`gaps`]), what recordings of a roundabout say about its drivers
//! ([`measure`]), the world's parameters fitted to them ([`calibrate`], over the estimators of
//! [`fit`]), and how far the world still drives from them ([`realism`], on traffic
//! [`simulate`]d on the recordings' map). `pipeline sim calibrate` and `pipeline sim realism`
//! run it.

pub mod calibrate;
pub mod decisions;
pub mod fit;
pub mod gaps;
pub mod measure;
pub mod realism;
pub mod simulate;
