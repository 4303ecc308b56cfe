// A torus (major radius 0.06 m, tube radius 0.02 m): a concave shape.
SetFactory("OpenCASCADE");
Torus(1) = {0, 0, 0, 0.06, 0.02};
Mesh.CharacteristicLengthMin = 0.01;
Mesh.CharacteristicLengthMax = 0.01;
