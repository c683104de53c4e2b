//! FMI 3.0 co-simulation glue (in progress).

use std::sync::LazyLock;

/// The FMI 3 model description, as shipped in the FMU.
pub const MODEL_DESCRIPTION: &str = include_str!("../fmi3/modelDescription.xml");

/// The instantiation token the model description declares.
pub static TOKEN: LazyLock<&'static str> =
    LazyLock::new(|| crate::xml_attribute(MODEL_DESCRIPTION, "instantiationToken"));
