"""Body geometry: product-of-exponentials kinematics, body models, flesh primitives, the camera model."""
