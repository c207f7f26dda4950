MNI Tag Point File
Volumes = 1;
% Volume 1 produced by VTK

Points =
 -23.5625 17.125 40 "nasion"
 0 -35.75 -12.375 "inion"
 61.4375 2.5 -7.8125 "left tragus";
