//! Traffic calibrated to real drivers: what recordings of a roundabout say about its
//! drivers ([`measure`]), the world's parameters fitted to them ([`calibrate`], over the
//! estimators of [`fit`]), and how far the world still drives from them ([`realism`], on
//! traffic [`simulate`]d on the recordings' map).

pub mod calibrate;
pub mod fit;
pub mod measure;
pub mod realism;
pub mod simulate;
