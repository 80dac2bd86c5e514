"""Body geometry: product-of-exponentials kinematics, body models, flesh primitives, the camera model, and ray-cast
rendering of the model (depth, labels, silhouettes)."""
