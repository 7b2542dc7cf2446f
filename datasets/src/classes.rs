//! The one class table of the project: 0 road, 1 lane marking, 2 vehicle, 3 human,
//! 4 other, and 255 for pixels a loss must ignore (unlabelled, padding, classes a source
//! cannot label). Labels on disk are single-channel PNGs holding these ids.

use serde::{Deserialize, Serialize};

/// A target class; the discriminant is the label value written to disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum Class {
    Road = 0,
    LaneMarking = 1,
    Vehicle = 2,
    Human = 3,
    Other = 4,
}

/// Label value of pixels the loss ignores (void, padding after a geometric transform).
pub const IGNORE: u8 = 255;

/// Name of [`IGNORE`] in class maps, cards and reports.
pub const IGNORE_NAME: &str = "ignore";

/// Preview colour of [`IGNORE`].
pub const IGNORE_COLOR: [u8; 3] = [0, 0, 0];

/// Preview colour of a value that is not in the table (only a broken label has one).
pub const INVALID_COLOR: [u8; 3] = [255, 0, 255];

/// Number of real classes (ids `0..NUM_CLASSES`).
pub const NUM_CLASSES: usize = 5;

impl Class {
    /// Every class, in id order.
    pub const ALL: [Class; NUM_CLASSES] = [
        Class::Road,
        Class::LaneMarking,
        Class::Vehicle,
        Class::Human,
        Class::Other,
    ];

    /// The label value.
    pub const fn id(self) -> u8 {
        self as u8
    }

    /// The class with this label value; None for [`IGNORE`] and unknown values.
    pub const fn from_id(id: u8) -> Option<Class> {
        match id {
            0 => Some(Class::Road),
            1 => Some(Class::LaneMarking),
            2 => Some(Class::Vehicle),
            3 => Some(Class::Human),
            4 => Some(Class::Other),
            _ => None,
        }
    }

    /// Snake-case name used in class maps, cards and reports.
    pub const fn name(self) -> &'static str {
        match self {
            Class::Road => "road",
            Class::LaneMarking => "lane_marking",
            Class::Vehicle => "vehicle",
            Class::Human => "human",
            Class::Other => "other",
        }
    }

    /// The class of a name (as [`Class::name`] gives it).
    pub fn from_name(name: &str) -> Option<Class> {
        Class::ALL.into_iter().find(|c| c.name() == name)
    }

    /// What a source that cannot label this class calls its pixels, when that is known: lane
    /// markings are painted road, and CamVid and Cityscapes label them road. None for the other
    /// classes: a source that cannot label them does not say what it calls them instead.
    pub const fn folds_into(self) -> Option<Class> {
        match self {
            Class::LaneMarking => Some(Class::Road),
            Class::Road | Class::Vehicle | Class::Human | Class::Other => None,
        }
    }

    /// Colour in previews and in the rerun annotation context (Cityscapes-like where
    /// Cityscapes has the class; lane markings yellow so they stand out on road).
    pub const fn color(self) -> [u8; 3] {
        match self {
            Class::Road => [128, 64, 128],
            Class::LaneMarking => [255, 220, 0],
            Class::Vehicle => [0, 0, 142],
            Class::Human => [220, 20, 60],
            Class::Other => [110, 110, 110],
        }
    }
}

/// Whether a pixel labelled `label` by a source that cannot label class `class` may truly be
/// `class` ([`Class::folds_into`]): a lane-marking prediction on a pixel CamVid calls road.
pub fn may_stand_for(label: u8, class: u8) -> bool {
    Class::from_id(class)
        .and_then(Class::folds_into)
        .is_some_and(|into| into.id() == label)
}

/// Whether a label value may appear in a label file: a class id or [`IGNORE`].
pub const fn is_valid_label(value: u8) -> bool {
    (value as usize) < NUM_CLASSES || value == IGNORE
}

/// Preview colour of a label value (magenta for values outside the table).
pub const fn label_color(value: u8) -> [u8; 3] {
    match Class::from_id(value) {
        Some(class) => class.color(),
        None if value == IGNORE => IGNORE_COLOR,
        None => INVALID_COLOR,
    }
}

/// Name of a label value: the class name, `ignore`, or None for values outside the table.
pub fn label_name(value: u8) -> Option<&'static str> {
    match Class::from_id(value) {
        Some(class) => Some(class.name()),
        None if value == IGNORE => Some(IGNORE_NAME),
        None => None,
    }
}

/// A label value from a name: a class name or `ignore`.
pub fn label_from_name(name: &str) -> Option<u8> {
    if name == IGNORE_NAME {
        Some(IGNORE)
    } else {
        Class::from_name(name).map(Class::id)
    }
}

/// One row of the class table as cards and reports write it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ClassEntry {
    pub id: u8,
    pub name: String,
    pub color: [u8; 3],
}

/// The class table, ignore last: what every card records.
pub fn class_table() -> Vec<ClassEntry> {
    Class::ALL
        .iter()
        .map(|c| ClassEntry {
            id: c.id(),
            name: c.name().to_owned(),
            color: c.color(),
        })
        .chain(std::iter::once(ClassEntry {
            id: IGNORE,
            name: IGNORE_NAME.to_owned(),
            color: IGNORE_COLOR,
        }))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_names_and_validity_agree() {
        for class in Class::ALL {
            assert_eq!(Class::from_id(class.id()), Some(class));
            assert_eq!(Class::from_name(class.name()), Some(class));
            assert_eq!(label_from_name(class.name()), Some(class.id()));
        }
        let valid: Vec<u8> = (0..=255u8).filter(|&v| is_valid_label(v)).collect();
        assert_eq!(valid, vec![0, 1, 2, 3, 4, 255]);
        assert_eq!(label_from_name("ignore"), Some(IGNORE));
        assert_eq!(label_name(7), None);
        assert_eq!(label_color(7), INVALID_COLOR);
        assert_eq!(class_table().len(), NUM_CLASSES + 1);
    }
}
