"""Front-end image measurements that need no map: image sharpness, the camera's turn from
the shift of small images. Tracking's motion priors use them."""
