//! Scene description: reading USD ASCII layers ([`usda`]) and binary ones (crate files and
//! usdz packages, [`usdc`]) into one syntax tree, typed values ([`value`]), values at a time ([`time`]) and composing
//! layers into a renderable prim tree ([`stage`]).

pub mod mtlx;
pub mod stage;
pub mod time;
pub mod usda;
pub mod usdc;
pub mod value;

pub use stage::{Attribute, Prim, PrimId, Relationship, Stage};
pub use time::TimeCode;
pub use usda::{Layer, LayerMetadata, ListOp, ListOpKind, PrimSpec, Specifier};
pub use value::{AssetPath, ScalarType, Value, ValueType};
